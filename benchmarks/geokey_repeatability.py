"""GeoKey's repeatability on validation sequences, for the shipped detector and experimental variants.

Repeatability is the protocol's (`geofeat.train.detector.repeatability`: ground-truth pairs < 3 px
over min(reference, target keypoints kept), the MS a perfect descriptor would reach), at 1024 and
2048 keypoints. No descriptor is computed, so a run over 9 sequences takes about 10 s: a quick
check for a detector idea before `geofeat bench`.

Variants (each patches one step of `geofeat.detectors.geokey` for the run; the shipped weights
score every variant):
- `shipped`: GeoKey as shipped.
- `foreshortened-3`, `foreshortened-7`, `foreshortened`: the cornerness cue(s) (`log_eig_3`,
  `log_eig_7`, both) measured on the surface instead of the image: the smaller eigenvalue of
  G^-1 M, with M the image structure tensor and G the surface's metric tensor in image coordinates
  (from the depth, smoothed by a Gaussian of 2 px), rescaled to image pixels at the frame's median
  depth. A corner seen obliquely is then ranked as if seen face-on.
- `quadratic-peak`: sub-pixel peaks by a full 2-D quadratic fit of the 3 x 3 cornerness
  (with the cross term) instead of two 1-D parabolas.
- `normalised-8`, `normalised-4`: the cornerness cues measured on the image with its local contrast
  normalised, (I - mean) / (std + 0.02) over a Gaussian of 8 / 4 px, rescaled to the image cue's
  median: corners ranked regardless of shading.
- `shading-24`, `shading-48`: every cue that scales with the image's contrast divided by the local
  mean brightness (a Gaussian of 24 / 48 px, plus 5 grey levels; the image is in [0, 1]), squared for the cornerness cues,
  rescaled to the cue's median: corners ranked as if the cloth were evenly lit (moving lights and
  folds shade it).
- `half-res-cornerness`: the half-resolution candidates' cornerness cues read on the half-resolution
  image (their own scale), shifted to the full-resolution cue's median over those candidates.
- `blur-0.7`, `blur-1.0`: the whole detection (candidates and cues) on the gray image blurred by a
  Gaussian of 0.7 / 1.0 px: fewer corners made by the image noise.
- `bilateral-2`, `bilateral-4`, `nlmeans-1`, `nlmeans-2`: the whole detection on the image denoised
  by a filter that keeps edges and corners, scaled to the frame's noise level sigma: a bilateral
  filter (range 2 / 4 x sigma) or non-local means (h = 1 / 2 x sigma).
- `half-octave`: up to 3000 more candidates found on the image resized by 2^-0.5, between the two
  pyramid levels (level cue 0.5, so the shipped level term scores them halfway).
- `surface-cap-100`, `-120`, `-150`: at most one keypoint per 100 / 120 / 150 pixels with depth, so
  that a frame whose surface covers little of the image returns fewer keypoints.
- `noise-floor-1`, `noise-floor-3`: candidates whose cornerness (3 px window, at their level) is below
  1 / 3 x the 99th percentile that pure noise of the frame's level would give are dropped. The noise
  level is the frame's robust estimate (median absolute 3 x 3 Laplacian, Immerkaer's mask).

    PYTHONPATH=src python benchmarks/geokey_repeatability.py out/det2/val/*hard* --variants shipped,foreshortened
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

from geofeat.detectors import cues, geokey
from geofeat.train.detector import repeatability


def foreshortened_cue_maps(windows: tuple[int, ...]):
    """A `cues.cue_maps` whose `log_eig_<w>` maps (w in `windows`) are measured on the surface."""
    image_cue_maps = cues.cue_maps

    def cue_maps(frame, depth_cues=True):
        maps = image_cue_maps(frame, depth_cues)
        fx, fy, cx, cy = frame.K[0, 0], frame.K[1, 1], frame.K[0, 2], frame.K[1, 2]
        depth = frame.depth.astype(np.float32)
        valid = (depth > 0).astype(np.float32)
        num, den = cv2.GaussianBlur(depth * valid, (0, 0), 2.0), cv2.GaussianBlur(valid, (0, 0), 2.0)
        z = np.where(den > 1e-3, num / np.maximum(den, 1e-3), 0).astype(np.float32)
        v, u = np.mgrid[0:z.shape[0], 0:z.shape[1]].astype(np.float32)
        xyz = [((u - cx) / fx * z).astype(np.float32), ((v - cy) / fy * z).astype(np.float32), z]
        Pu = np.stack([cv2.Sobel(c, cv2.CV_32F, 1, 0, ksize=3) / 8 for c in xyz], -1)  # dP / du, metres per px
        Pv = np.stack([cv2.Sobel(c, cv2.CV_32F, 0, 1, ksize=3) / 8 for c in xyz], -1)
        a, b, c = (Pu * Pu).sum(-1), (Pu * Pv).sum(-1), (Pv * Pv).sum(-1)  # metric tensor G
        det = np.maximum(a * c - b * b, 1e-30)
        px2 = (np.median(depth[depth > 0]) / fx) ** 2 if (depth > 0).any() else 1.0  # m^2 per px^2 at the median depth
        g = frame.image.astype(np.float32)
        gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
        for w in windows:
            Ixx, Ixy, Iyy = (cv2.boxFilter(p, -1, (w, w)) for p in (gx * gx, gx * gy, gy * gy))
            m11, m12 = (c * Ixx - b * Ixy) / det, (c * Ixy - b * Iyy) / det  # G^-1 M
            m21, m22 = (a * Ixy - b * Ixx) / det, (a * Iyy - b * Ixy) / det
            half = (m11 + m22) / 2
            with np.errstate(over="ignore", invalid="ignore"):  # flat or missing depth: det is clamped
                smallest = (half - np.sqrt(np.maximum(half * half - (m11 * m22 - m12 * m21), 0))) * px2
            image = maps[f"log_eig_{w}"]
            ok = (depth > 0) & (image > 0)
            scale = np.median(image[ok]) / max(float(np.median(smallest[ok])), 1e-30) if ok.any() else 1.0
            maps[f"log_eig_{w}"] = np.where(depth > 0, smallest * scale, image).astype(np.float32)
        return maps

    return cue_maps


def normalised_cue_maps(sigma: float):
    """A `cues.cue_maps` whose cornerness cues come from the contrast-normalised image."""
    image_cue_maps = cues.cue_maps

    def cue_maps(frame, depth_cues=True):
        maps = image_cue_maps(frame, depth_cues)
        g = frame.image.astype(np.float32)
        mean = cv2.GaussianBlur(g, (0, 0), sigma)
        std = np.sqrt(np.maximum(cv2.GaussianBlur(g * g, (0, 0), sigma) - mean * mean, 0))
        normalised = (g - mean) / (std + 0.02)
        for w in (3, 7):
            image, new = maps[f"log_eig_{w}"], cv2.cornerMinEigenVal(normalised, w, 3)
            ok = (frame.depth > 0) & (image > 0) & (new > 0)
            if ok.any():
                maps[f"log_eig_{w}"] = (new * (np.median(image[ok]) / np.median(new[ok]))).astype(np.float32)
        return maps

    return cue_maps


#: the intensity-linear image cues of `cues.cue_maps`, and the two that are quadratic in it (cornerness)
LINEAR_CUES = ("log_grad_1", "log_grad_3", "log_dog", "log_std_9", "log_std_21")
QUADRATIC_CUES = ("log_eig_3", "log_eig_7")


def shading_normalised_cue_maps(sigma: float, floor: float = 5.0 / 255.0):
    """A `cues.cue_maps` whose contrast cues are divided by the local mean brightness (squared for the
    cornerness), rescaled to their median over pixels with depth."""
    image_cue_maps = cues.cue_maps

    def cue_maps(frame, depth_cues=True):
        maps = image_cue_maps(frame, depth_cues)
        mean = cv2.GaussianBlur(frame.image.astype(np.float32), (0, 0), sigma) + floor
        for name in LINEAR_CUES + QUADRATIC_CUES:
            old = maps[name]
            new = old / mean ** (2 if name in QUADRATIC_CUES else 1)
            ok = (frame.depth > 0) & (old > 0)
            if ok.any():
                new = new * (np.median(old[ok]) / max(float(np.median(new[ok])), 1e-12))
            maps[name] = new.astype(np.float32)
        return maps

    return cue_maps


def half_res_features(frame, cands, depth_cues=True):
    """`geokey.candidate_features` with the level-1 candidates' cornerness read at half resolution."""
    from geofeat.detectors.cues import CUE_NAMES

    features = FEATURES(frame, cands, depth_cues)
    half = cv2.pyrDown(frame.image.astype(np.float32))
    level1 = cands.level == 1
    if level1.sum() < 10:
        return features
    xy = (cands.xy[level1] + 0.5) / 2 - 0.5
    xi = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, half.shape[1] - 1)
    yi = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, half.shape[0] - 1)
    for w in (3, 7):
        col = CUE_NAMES.index(f"log_eig_{w}")
        value = np.log(np.abs(cv2.cornerMinEigenVal(half, w, 3)[yi, xi]) + cues.LOG_EPS[f"log_eig_{w}"])
        features[level1, col] = value - np.median(value) + np.median(features[level1, col])
    return features


def quadratic_peaks(response: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """`geokey.refine_peaks` by a 2-D quadratic through the 3 x 3 neighbourhood (offset -H^-1 g,
    clipped to half a pixel); the 1-D parabolas where the fit is not a maximum."""
    H, W = response.shape
    x = np.clip(np.rint(xy[:, 0]).astype(np.int64), 1, W - 2)
    y = np.clip(np.rint(xy[:, 1]).astype(np.int64), 1, H - 2)

    def r(dy, dx):
        return response[y + dy, x + dx].astype(np.float64)

    gx, gy = (r(0, 1) - r(0, -1)) / 2, (r(1, 0) - r(-1, 0)) / 2
    hxx, hyy = r(0, 1) - 2 * r(0, 0) + r(0, -1), r(1, 0) - 2 * r(0, 0) + r(-1, 0)
    hxy = (r(1, 1) - r(1, -1) - r(-1, 1) + r(-1, -1)) / 4
    det = hxx * hyy - hxy * hxy
    peak = (det > 1e-20) & (hxx < 0)
    safe = np.where(peak, det, 1.0)
    separable = PARABOLAS(response, xy)
    dx = np.where(peak, np.clip(-(hyy * gx - hxy * gy) / safe, -0.5, 0.5), separable[:, 0] - x)
    dy = np.where(peak, np.clip(-(hxx * gy - hxy * gx) / safe, -0.5, 0.5), separable[:, 1] - y)
    return np.stack([x + dx, y + dy], axis=1)


def blurred_detector(sigma: float):
    """`geokey.detect_geokey` on the gray image blurred by a Gaussian of `sigma` px."""
    from geofeat.frame import RGBDFrame

    def detect(frame, n):
        return DETECT(RGBDFrame(cv2.GaussianBlur(frame.image, (0, 0), sigma), frame.depth, frame.K), n)

    return detect


def denoised_detector(method: str, strength: float, diameter: int = 5, space: float = 1.5):
    """`geokey.detect_geokey` on the image denoised edge-preservingly, scaled to the frame's noise
    level sigma (`geokey.noise_level`): "bilateral" (`diameter` px, range sigma `strength` x sigma,
    spatial sigma `space` px; the defaults are `geokey.detection_image`'s) or "nlmeans" (OpenCV's
    non-local means on the 8-bit image, h = `strength` x sigma)."""
    def detect(frame, n):
        g = frame.image.astype(np.float32)  # gray, 0..1
        sigma = max(geokey.noise_level(g), 1e-4)
        if method == "bilateral":
            image = cv2.bilateralFilter(g, diameter, strength * sigma, space)
        else:
            as_bytes = np.clip(np.rint(g * 255), 0, 255).astype(np.uint8)
            image = cv2.fastNlMeansDenoising(as_bytes, None, max(strength * sigma * 255, 0.1), 5, 15).astype(np.float32) / 255
        return DETECT(frame.with_image(image), n, denoise=0.0)

    return detect


def denoised_candidates(strength: float, diameter: int = 5, space: float = 1.5):
    """`geokey.candidates` found and localised on the bilaterally denoised image (as
    `denoised_detector`), while the scorer's cues stay on the image as it is."""
    def candidates(frame, max_candidates=geokey.MAX_CANDIDATES):
        g = frame.image.astype(np.float32)
        image = cv2.bilateralFilter(g, diameter, strength * max(geokey.noise_level(g), 1e-4), space)
        return CANDIDATES(frame.with_image(image), max_candidates)

    return candidates


def noise_floor_candidates(factor: float, quantile: float = 0.99):
    """`geokey.candidates` without the candidates whose 3 px cornerness at their level is below
    `factor` x the `quantile` of the cornerness of white noise at the frame's noise level."""
    unit: dict = {}

    def candidates(frame, max_candidates=geokey.MAX_CANDIDATES):
        cands = CANDIDATES(frame, max_candidates)
        g = frame.image.astype(np.float32)
        sigma = geokey.noise_level(g)
        if g.shape not in unit:  # cornerness quantiles of unit-variance noise at each level
            noise, unit[g.shape] = np.random.default_rng(0).normal(0.0, 1.0, g.shape).astype(np.float32), []
            for level in range(len(max_candidates)):
                noise = cv2.pyrDown(noise) if level else noise
                unit[g.shape].append(float(np.quantile(cv2.cornerMinEigenVal(noise, geokey.CORNER_WINDOW_PX, 3), quantile)))
        keep = np.ones(len(cands), bool)
        image = g
        for level in range(len(max_candidates)):
            image = cv2.pyrDown(image) if level else image
            response = cv2.cornerMinEigenVal(image, geokey.CORNER_WINDOW_PX, 3)
            on = cands.level == level
            xy = (cands.xy[on] + 0.5) / 2**level - 0.5
            xi = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, image.shape[1] - 1)
            yi = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, image.shape[0] - 1)
            keep[on] = response[yi, xi] >= factor * unit[g.shape][level] * sigma**2
        return cands[keep]

    return candidates


def half_octave_candidates(count: int = 3000):
    """`geokey.candidates` plus up to `count` candidates found on the image resized by 2^-0.5 (area
    interpolation), between the full- and half-resolution levels, with level cue 0.5: a surface
    seen at 0.7x the reference's scale then has a level of its own, not only the 2x steps."""
    def candidates(frame, max_candidates=geokey.MAX_CANDIDATES):
        cands = CANDIDATES(frame, max_candidates)
        g = frame.image.astype(np.float32)
        H, W = g.shape
        w, h = int(round(W / np.sqrt(2))), int(round(H / np.sqrt(2)))
        image = cv2.resize(g, (w, h), interpolation=cv2.INTER_AREA)
        mask = cv2.resize((frame.depth > 0).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
        pts = cv2.goodFeaturesToTrack(image, maxCorners=count, qualityLevel=1e-4, minDistance=geokey.CANDIDATE_SPACING_PX,
                                      mask=mask, blockSize=geokey.CORNER_WINDOW_PX)
        if pts is None:
            return cands
        pts = geokey.refine_peaks(cv2.cornerMinEigenVal(image, geokey.CORNER_WINDOW_PX, 3), pts.reshape(-1, 2))
        xy = np.stack([(pts[:, 0] + 0.5) * W / w - 0.5, (pts[:, 1] + 0.5) * H / h - 0.5], axis=1)
        inside = ((xy[:, 0] >= geokey.BORDER_PX) & (xy[:, 0] <= W - 1 - geokey.BORDER_PX)
                  & (xy[:, 1] >= geokey.BORDER_PX) & (xy[:, 1] <= H - 1 - geokey.BORDER_PX))
        xy = xy[inside]
        edge = geokey.depth_edge_distance(frame.depth, float(frame.K[0, 0]), geokey.DEPTH_EDGE_STEP_FOOTPRINTS,
                                          fy=float(frame.K[1, 1]))
        xy = xy[edge[np.rint(xy[:, 1]).astype(np.int64), np.rint(xy[:, 0]).astype(np.int64)] >= geokey.DEPTH_EDGE_MARGIN_PX]
        return geokey.Candidates(np.concatenate([cands.xy, xy]),
                                 np.concatenate([cands.level.astype(np.float64), np.full(len(xy), 0.5)]))

    return candidates


def surface_capped_detector(pixels_per_keypoint: float):
    """GeoKey returning at most one keypoint per `pixels_per_keypoint` pixels with depth: a frame
    whose surface covers little of the image (a far or crumpled view) gets fewer keypoints."""
    def detect(frame, n):
        cap = int(np.count_nonzero(frame.depth > 0) / pixels_per_keypoint)
        return DETECT(frame, max(1, min(n, cap)))

    return detect


DETECT = geokey.detect_geokey
CANDIDATES = geokey.candidates
PARABOLAS = geokey.refine_peaks
FEATURES = geokey.candidate_features
VARIANTS = {
    "shipped": {},
    "foreshortened-3": {"cue_maps": lambda: foreshortened_cue_maps((3,))},
    "foreshortened-7": {"cue_maps": lambda: foreshortened_cue_maps((7,))},
    "foreshortened": {"cue_maps": lambda: foreshortened_cue_maps((3, 7))},
    "quadratic-peak": {"refine_peaks": lambda: quadratic_peaks},
    "normalised-8": {"cue_maps": lambda: normalised_cue_maps(8.0)},
    "normalised-4": {"cue_maps": lambda: normalised_cue_maps(4.0)},
    "half-res-cornerness": {"candidate_features": lambda: half_res_features},
    "shading-24": {"cue_maps": lambda: shading_normalised_cue_maps(24.0)},
    "shading-48": {"cue_maps": lambda: shading_normalised_cue_maps(48.0)},
    "blur-0.7": {"detector": lambda: blurred_detector(0.7)},
    "blur-1.0": {"detector": lambda: blurred_detector(1.0)},
    "noise-floor-1": {"candidates": lambda: noise_floor_candidates(1.0)},
    "noise-floor-3": {"candidates": lambda: noise_floor_candidates(3.0)},
    "bilateral-2": {"detector": lambda: denoised_detector("bilateral", 2.0)},
    "bilateral-4": {"detector": lambda: denoised_detector("bilateral", 4.0)},
    "bilateral-3": {"detector": lambda: denoised_detector("bilateral", 3.0)},
    "bilateral-6": {"detector": lambda: denoised_detector("bilateral", 6.0)},
    "bilateral-8": {"detector": lambda: denoised_detector("bilateral", 8.0)},
    "bilateral-4-d3": {"detector": lambda: denoised_detector("bilateral", 4.0, 3, 1.0)},
    "bilateral-4-d7": {"detector": lambda: denoised_detector("bilateral", 4.0, 7, 2.0)},
    "bilateral-cands-2": {"candidates": lambda: denoised_candidates(2.0)},
    "bilateral-cands-4": {"candidates": lambda: denoised_candidates(4.0)},
    "bilateral-cands-4-d7": {"candidates": lambda: denoised_candidates(4.0, 7, 2.0)},
    "surface-cap-100": {"detector": lambda: surface_capped_detector(100.0)},
    "surface-cap-120": {"detector": lambda: surface_capped_detector(120.0)},
    "surface-cap-150": {"detector": lambda: surface_capped_detector(150.0)},
    "half-octave": {"candidates": lambda: half_octave_candidates(3000)},
    "nlmeans-1": {"detector": lambda: denoised_detector("nlmeans", 1.0)},
    "nlmeans-2": {"detector": lambda: denoised_detector("nlmeans", 2.0)},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequences", nargs="+", type=Path, help="simulated sequence folders with ground truth")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {', '.join(VARIANTS)}")
    ap.add_argument("--keypoints", default="1024,2048")
    a = ap.parse_args()
    counts = [int(n) for n in a.keypoints.split(",")]
    print(f"{len(a.sequences)} sequences; load average {os.getloadavg()[0]:.2f}")
    print("| variant | " + " | ".join(f"repeatability / ground-truth pairs per pair / reference keypoints, {n}" for n in counts) + " |")
    print("|---|" + "---|" * len(counts))
    originals = {"cue_maps": geokey.cue_maps, "refine_peaks": geokey.refine_peaks,
                 "candidate_features": geokey.candidate_features, "candidates": geokey.candidates}
    for name in a.variants.split(","):
        if name not in VARIANTS:
            raise SystemExit(f"--variants: unknown {name!r}; known: {', '.join(VARIANTS)}")
        detector = lambda frame, k: geokey.detect_geokey(frame, k)  # noqa: E731 (reads the patched module)
        for attr, make in VARIANTS[name].items():
            if attr == "detector":
                detector = make()
            else:
                setattr(geokey, attr, make())
        t = time.perf_counter()
        cells = []
        for n in counts:
            r = repeatability(a.sequences, detector, n)
            cells.append(f"{r['repeatability']:.3f} / {r['pairs']:.0f} / {r['n_ref']:.0f}")
        for attr, fn in originals.items():
            setattr(geokey, attr, fn)
        print(f"| {name} | " + " | ".join(cells) + f" |   ({time.perf_counter() - t:.0f} s)")


if __name__ == "__main__":
    main()
