"""GeoKey: a learned, deformation-aware keypoint detector for RGB-D frames.

Three steps, all vectorised:

1. **Candidates.** Well-localised corners (the structure tensor's smaller eigenvalue, Shi-Tomasi)
   at full and half resolution, refined to sub-pixel by a parabola through the cornerness peak, on
   pixels with depth, away from depth discontinuities (occlusion contours slide as the cloth
   moves). They are dense (several thousand per 640 x 480 frame), so the detector can afford to be
   choosy.
2. **Learned score.** logit = a linear function of image cues (cornerness, gradient, contrast at
   a few scales) + a small MLP of depth cues (slope, curvature, distance to a depth edge, depth
   coverage; `geofeat.detectors.cues`). It predicts the probability that the point is found again,
   at the same surface point, in another view of the bent surface, and matched there. The image
   part is linear on purpose: the ranking of two corners by contrast and cornerness then stays the
   same in every view, which a free non-linear mix learned on renders did not do. It is trained on simulated sequences with exact
   correspondences (`geofeat train-detector`, `geofeat.train.detector`).
3. **Selection.** Non-maximum suppression of the scores within `nms_radius` pixels; candidates whose
   logit is below the model's `threshold` are dropped (like SIFT's contrast threshold, so a frame
   with little good surface gives fewer keypoints), except the best `min_fraction` of the frame's
   candidates, which are always kept; then the `n` best.

Weights trained with `train-detector --denoise K` first pass the image through an edge-preserving
filter scaled to its noise level (`detection_image`); the shipped weights do not (K = 0: on our
validation sets it moved matching score from clean renders to noisy ones, BENCHMARKS.md).

The weights are a small `.npz` archive (whatever the file's extension) of numpy arrays: inference
needs neither torch nor a GPU.
"""

from __future__ import annotations

import numbers
import warnings
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from stat import S_ISDIR

import cv2
import numpy as np

from ..frame import RGBDFrame
from ..inputs import check_non_negative
from ..keypoints import Keypoints, _check_n, check_mask
from .cues import CUE_NAMES, IMAGE_CUES, cue_features, cue_maps, depth_edge_distance

#: The shipped weights.
SHIPPED_WEIGHTS = Path(__file__).resolve().parent.parent / "data" / "geokey.npz"
#: Candidate corners per pyramid level (level 0 = full resolution, level 1 = half).
MAX_CANDIDATES = (6000, 2000)
#: Minimum distance between candidates of one level, pixels of that level.
CANDIDATE_SPACING_PX = 3
#: Window of the structure tensor whose smaller eigenvalue ranks the candidates, pixels of the level
#: (chosen on validation: 3 px gave GeoPatch MS 0.294 against 0.277 for 5 px and 0.248 for 7 px).
CORNER_WINDOW_PX = 3
#: Default suppression radius between selected keypoints, pixels.
NMS_RADIUS_PX = 3
#: Candidates closer than this to the image border are dropped, pixels.
BORDER_PX = 4
#: Candidates closer than this to a depth discontinuity or a hole are dropped, pixels
#: (`cues.depth_edge_distance`). There the corner is an occlusion contour, a T-junction of two
#: surfaces that slides as the cloth moves, and the geodesic patch around it is cut. Chosen on
#: validation (BENCHMARKS.md, "GeoKey v3.4"): GeoPatch MS +5 to +9 %, correct matches within 4 %.
DEPTH_EDGE_MARGIN_PX = 3.0
#: A depth discontinuity for DEPTH_EDGE_MARGIN_PX: a step of more than this many pixel footprints between
#: neighbours (slopes up to 84 degrees pass). `cues`' 4 footprints also cut steep slopes of the cloth,
#: and lost a quarter of the correct matches on validation.
DEPTH_EDGE_STEP_FOOTPRINTS = 10.0


#: Immerkaer's noise mask: a 3 x 3 difference of Laplacians whose response to white noise of unit
#: standard deviation has standard deviation 6 (the root of the sum of its squared weights) and which
#: cancels on planes and on most smooth shading.
NOISE_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
#: The edge-preserving filter of `detection_image`: a bilateral filter of this diameter and spatial
#: sigma, pixels (its range sigma is the model's `denoise` x the frame's noise level).
BILATERAL_DIAMETER_PX = 5
BILATERAL_SPACE_PX = 1.5


@dataclass(frozen=True)
class GeoKeyModel:
    """The learned scorer, numpy arrays.

    Attributes:
        mean, std: (D,) feature standardisation, D = len(CUE_NAMES).
        linear: (len(IMAGE_CUES),) weights of the standardised image cues.
        weights: [(len(CONTEXT_CUES), H1), ..., (Hk, 1)] layer matrices of the depth-cue MLP; empty
            when training found that the depth cues do not help (the score is then linear).
        biases: [(H1,), ..., (1,)] its biases.
        nms_radius: suppression radius chosen on validation data, pixels.
        threshold: keypoints whose logit is below this are not returned (-inf: none dropped; weights
            files written before the threshold existed load with -inf). Chosen on validation data.
        min_fraction: the best this fraction of the frame's candidates (after suppression) are kept
            whatever their logit. The threshold is calibrated on renders, and real images score
            lower overall; this floor keeps their keypoint count (0: no floor).
        denoise: the range of the bilateral filter applied to the image before detection, in
            multiples of the frame's noise level (`noise_level`); 0 = the image as it is (weights
            files written before the setting existed load with 0). Noise moves 3 px corners between
            views; the filter smooths it out and keeps the corners (`detection_image`).
    """

    mean: np.ndarray
    std: np.ndarray
    linear: np.ndarray
    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    nms_radius: float = NMS_RADIUS_PX
    threshold: float = -np.inf
    min_fraction: float = 0.0
    denoise: float = 0.0

    def score(self, features: np.ndarray) -> np.ndarray:
        """(N, D) cue features -> (N,) float32 logits (higher = more likely found again and matched)."""
        x = (np.asarray(features, np.float32) - self.mean) / self.std
        n_image = len(IMAGE_CUES)
        score = x[:, :n_image] @ self.linear
        if self.weights:
            h = x[:, n_image:]
            for k, (w, b) in enumerate(zip(self.weights, self.biases)):
                h = h @ w + b
                if k < len(self.weights) - 1:
                    h = np.maximum(h, 0.0)
            score = score + h[:, 0]
        return score.astype(np.float32)

    @property
    def uses_depth_cues(self) -> bool:
        """True when the score has the depth-cue MLP."""
        return bool(self.weights)

    def save(self, path: str | Path) -> None:
        """Write the model to `path` as an .npz archive (the extension is kept as given), whole or not
        at all (`geofeat.outputs.write_npz`)."""
        from ..outputs import write_npz

        arrays = {"mean": self.mean, "std": self.std, "linear": self.linear,
                  "nms_radius": np.float32(self.nms_radius), "threshold": np.float32(self.threshold),
                  "min_fraction": np.float32(self.min_fraction), "denoise": np.float32(self.denoise),
                  "cue_names": np.array(CUE_NAMES)}
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            arrays[f"w{k}"], arrays[f"b{k}"] = w, b
        write_npz(path, arrays)


def load_geokey(path: str | Path | None = None) -> GeoKeyModel:
    """Load GeoKey weights (default: the shipped ones).

    Raises:
        ValueError naming the file when it is missing, a folder, corrupt, made for other cues, or
        holds non-finite arrays or settings out of range.
    """
    path = (Path(path) if path is not None else SHIPPED_WEIGHTS).resolve()
    try:
        stat = path.stat()  # one call per detection: the stamp makes a file rewritten since be read again
    except OSError:
        raise ValueError(f"detector weights: {path} does not exist") from None
    if S_ISDIR(stat.st_mode):
        raise ValueError(f"detector weights: {path} is a folder, not a weights file")
    return _load(str(path), (stat.st_mtime_ns, stat.st_size, stat.st_ino))


def check_settings(nms_radius, threshold, min_fraction, denoise=0.0) -> tuple[float, float, float, float]:
    """The selection settings as floats: `nms_radius` a finite number of pixels >= 0, `threshold` a
    number (not NaN; +-inf allowed), `min_fraction` in [0, 1], `denoise` a finite number >= 0.
    ValueError naming the setting otherwise."""
    def number(value, what: str, expected: str) -> float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or np.isnan(value):
            raise ValueError(f"{what}: expected {expected}, got {value!r}")
        return float(value)

    nms_radius = check_non_negative(nms_radius, "nms_radius")
    threshold = number(threshold, "threshold", "a number or -inf")
    min_fraction = number(min_fraction, "min_fraction", "a fraction in [0, 1]")
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction: expected a fraction in [0, 1], got {min_fraction}")
    denoise = check_non_negative(denoise, "denoise")
    return nms_radius, threshold, min_fraction, denoise


@lru_cache(maxsize=4)
def _load(path: str, stamp: tuple[int, int, int]) -> GeoKeyModel:
    """The weights at `path` as they were at `stamp` (modification time, size, inode of the file)."""
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # an .npy file: np.load gives the array itself
            raise ValueError("one numpy array, not an .npz archive of arrays")
        with loaded as a:
            arrays = {k: a[k] for k in a.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise ValueError(f"detector weights: {path} is not a GeoKey weights file ({error})") from None
    if any(name.endswith("data.pkl") for name in arrays):  # a torch archive is a zip too, read as arrays
        raise ValueError(f"detector weights: {path} holds PyTorch weights (a descriptor's, from `geofeat train`?), "
                         "not a detector's: pass GeoPatch weights as --descriptors geopatch=PATH, and GeoKey "
                         "weights from `geofeat train-detector` as --detector geokey=PATH")
    if "cue_names" not in arrays:
        raise ValueError(f"detector weights: {path} is not a GeoKey weights file (no cue_names array); "
                         "`geofeat train-detector` writes them")
    names = tuple(str(s) for s in arrays["cue_names"])
    if names != CUE_NAMES:
        i = next((i for i, (a, b) in enumerate(zip(names, CUE_NAMES)) if a != b), min(len(names), len(CUE_NAMES)))
        got = repr(names[i]) if i < len(names) else "missing"
        want = repr(CUE_NAMES[i]) if i < len(CUE_NAMES) else "none"
        raise ValueError(f"detector weights: {path} is not a GeoKey weights file for this version "
                         f"({len(names)} cues, expected {len(CUE_NAMES)}; cue {i} is {got}, expected {want})")
    if "linear" not in arrays:
        raise ValueError(f"detector weights: {path} is not a GeoKey weights file for this version (no linear array)")
    try:
        k = sum(1 for name in arrays if name.startswith("w"))
        weights = tuple(arrays[f"w{i}"].astype(np.float32) for i in range(k))
        biases = tuple(arrays[f"b{i}"].astype(np.float32) for i in range(k))
        model = GeoKeyModel(arrays["mean"].astype(np.float32), arrays["std"].astype(np.float32),
                            arrays["linear"].astype(np.float32), weights, biases, float(arrays["nms_radius"]),
                            float(arrays.get("threshold", -np.inf)), float(arrays.get("min_fraction", 0.0)),
                            float(arrays.get("denoise", 0.0)))
        shapes = (model.mean.shape, model.std.shape, model.linear.shape)
        if shapes != ((len(CUE_NAMES),),) * 2 + ((len(IMAGE_CUES),),):
            raise ValueError(f"mean, std, linear of shapes {shapes}")
        if any(w.ndim != 2 for w in model.weights) or any(b.ndim != 1 for b in model.biases):
            raise ValueError(f"depth-cue layers of shapes {[w.shape for w in model.weights]}, biases "
                             f"{[b.shape for b in model.biases]}: expected matrices and vectors")
        if model.weights and model.weights[-1].shape[-1:] != (1,):
            raise ValueError(f"the depth-cue layers end in {model.weights[-1].shape[-1:]} values, not one logit")
        every = (model.mean, model.std, model.linear) + model.weights + model.biases
        if not all(np.isfinite(a).all() for a in every) or not (model.std > 0).all():
            raise ValueError("arrays with NaN or infinite values, or a std that is not positive")
        model.score(np.zeros((1, len(CUE_NAMES)), np.float32))  # the layers chain (a ValueError otherwise)
        check_settings(model.nms_radius, model.threshold, model.min_fraction, model.denoise)
    except (KeyError, TypeError, ValueError) as error:  # a missing array, or arrays of the wrong shapes
        raise ValueError(f"detector weights: {path} is not a complete GeoKey weights file ({error})") from None
    return model


@dataclass
class Candidates:
    """Candidate keypoints: xy (N, 2) float64 pixels (OpenCV convention), level (N,) int pyramid
    level (0 = full resolution, 1 = half)."""

    xy: np.ndarray
    level: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)

    def __getitem__(self, index) -> "Candidates":
        return Candidates(self.xy[index], self.level[index])

    @property
    def size(self) -> np.ndarray:
        """(N,) nominal diameter, pixels: 8 x 2^level."""
        return 8.0 * 2.0 ** self.level


def noise_level(image: np.ndarray, stride: int = 1) -> float:
    """Robust standard deviation of the noise of a (H, W) gray image, in its own units: the median
    absolute response to `NOISE_MASK` (Immerkaer's mask; the median instead of the mean, so that
    texture and edges weigh less), / 0.6745 / 6. 0 for images smaller than 3 x 3. `stride` > 1
    takes the median over every stride-th response in each direction (a quicker estimate)."""
    g = np.asarray(image, np.float32)
    if min(g.shape) < 3:
        return 0.0
    response = cv2.filter2D(g, -1, NOISE_MASK)[1:-1:stride, 1:-1:stride]
    return float(np.median(np.abs(response))) / (0.6745 * 6.0)


#: The corner strength that white noise reaches: the 99th percentile of `local_cornerness` on white
#: noise of unit standard deviation (a fixed 256 x 256 draw; the strength scales with the variance).
NOISE_CORNERNESS_PERCENTILE = 99.0
#: GeoKey warns when fewer than this share of a frame's keypoints are stronger corners than its
#: noise reaches (`noise_corner_share`): 0.09-0.12 on frames of pure noise of 1-10 grey levels,
#: 0.33-1.00 on the Kinect frame and on the reference and every other target frame of the 18
#: validation sequences (out/det2/val).
NOISE_KEYPOINT_SHARE = 0.2
#: Keypoints looked at by `noise_corner_share` (evenly spaced in the list): enough for a share
#: within about 5 per cent, a fraction of a millisecond.
NOISE_CHECK_KEYPOINTS = 128
#: ... and the noise level it compares them with is the median over every fourth pixel in each
#: direction (`noise_level`'s stride; within 1 % of the full median on the Kinect frame, pure noise and six
#: simulated frames).
NOISE_CHECK_STRIDE = 4


def local_cornerness(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(N,) corner strength of a (H, W) float gray image at (N, 2) pixel positions (x, y): the
    structure tensor's smaller eigenvalue (3 x 3 Sobel gradients summed over a 3 x 3 window, in
    squared image units) at the nearest pixel and its 8 neighbours, the largest of the nine.
    Positions within 4 px of the border are clamped inside."""
    g = np.asarray(image, np.float32)
    H, W = g.shape
    cx = np.clip(np.rint(xy[:, 0]).astype(np.int64), 4, W - 5)
    cy = np.clip(np.rint(xy[:, 1]).astype(np.int64), 4, H - 5)
    off = np.arange(-4, 5)
    patch = g[cy[:, None, None] + off[None, :, None], cx[:, None, None] + off[None, None, :]]  # (N, 9, 9)
    smooth_y = patch[:, :-2] + 2 * patch[:, 1:-1] + patch[:, 2:]  # (N, 7, 9)
    smooth_x = patch[:, :, :-2] + 2 * patch[:, :, 1:-1] + patch[:, :, 2:]  # (N, 9, 7)
    gx = (smooth_y[:, :, 2:] - smooth_y[:, :, :-2]) / 8.0  # (N, 7, 7)
    gy = (smooth_x[:, 2:] - smooth_x[:, :-2]) / 8.0

    def box3(a: np.ndarray) -> np.ndarray:  # (N, 7, 7) -> (N, 5, 5) sums over 3 x 3 windows
        rows = a[:, :-2] + a[:, 1:-1] + a[:, 2:]
        return rows[:, :, :-2] + rows[:, :, 1:-1] + rows[:, :, 2:]

    a, b, c = box3(gx * gx), box3(gx * gy), box3(gy * gy)
    smaller = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)  # (N, 5, 5)
    return smaller[:, 1:-1, 1:-1].reshape(len(xy), -1).max(axis=1)


@lru_cache(maxsize=1)
def _unit_noise_cornerness() -> float:
    """The NOISE_CORNERNESS_PERCENTILE-th percentile of `local_cornerness` on unit white noise."""
    noise = np.random.default_rng(0).standard_normal((256, 256)).astype(np.float32)
    yy, xx = np.mgrid[8:248, 8:248]
    return float(np.percentile(local_cornerness(noise, np.stack([xx.ravel(), yy.ravel()], 1)),
                               NOISE_CORNERNESS_PERCENTILE))


def noise_corner_share(image: np.ndarray, xy: np.ndarray) -> float:
    """Share of the keypoints at (N, 2) pixel positions (x, y) of a (H, W) gray image whose corner
    strength (`local_cornerness`) exceeds what the image's own noise (`noise_level`, as white noise)
    reaches at its 99th percentile; at most NOISE_CHECK_KEYPOINTS of them, evenly spaced, are looked
    at. 1.0 for an image without noise or without keypoints. Keypoints on a textureless surface are
    corners of its noise, which no other view repeats."""
    sigma = noise_level(image, stride=NOISE_CHECK_STRIDE)
    if len(xy) == 0 or sigma <= 0.0 or min(np.shape(image)) < 9:
        return 1.0
    pick = np.unique(np.linspace(0, len(xy) - 1, min(len(xy), NOISE_CHECK_KEYPOINTS)).astype(np.int64))
    strength = local_cornerness(image, np.asarray(xy, np.float64)[pick])
    return float(np.mean(strength > _unit_noise_cornerness() * sigma * sigma))


def detection_image(frame: RGBDFrame, denoise: float) -> RGBDFrame:
    """The frame GeoKey detects on: with `denoise` > 0, its gray image through a bilateral filter of
    BILATERAL_DIAMETER_PX and BILATERAL_SPACE_PX whose range sigma is `denoise` x `noise_level`, so
    that noise of any level is smoothed while corners, whose contrast is many noise levels, stay
    (same depth and intrinsics); the frame itself when `denoise` is 0 or the image has no noise."""
    sigma = noise_level(frame.image) if denoise > 0 else 0.0
    if sigma <= 0.0:
        return frame
    image = cv2.bilateralFilter(np.asarray(frame.image, np.float32), BILATERAL_DIAMETER_PX, denoise * sigma,
                                BILATERAL_SPACE_PX)
    return frame.with_image(image)


def candidates(frame: RGBDFrame, max_candidates: tuple[int, ...] = MAX_CANDIDATES) -> Candidates:
    """Corner candidates of `frame`, on pixels with depth, away from the border and at least
    DEPTH_EDGE_MARGIN_PX from a depth discontinuity or hole."""
    g = frame.image.astype(np.float32)
    H, W = g.shape
    has_depth = (frame.depth > 0).astype(np.uint8)
    out_xy, out_level = [], []
    image, mask = g, has_depth
    for level, count in enumerate(max_candidates):
        if level:
            image = cv2.pyrDown(image)
            mask = cv2.resize(mask, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_NEAREST)
        pts = cv2.goodFeaturesToTrack(image, maxCorners=int(count), qualityLevel=1e-4,
                                      minDistance=CANDIDATE_SPACING_PX, mask=mask, blockSize=CORNER_WINDOW_PX)
        if pts is None:
            continue
        pts = refine_peaks(cv2.cornerMinEigenVal(image, CORNER_WINDOW_PX, 3), pts.reshape(-1, 2))
        # cv2.pyrDown centres pixel i of a level on pixel 2 i of the level below (not on 2 i + 0.5, as
        # an area resize would), so level-l pixel i lies on full-resolution pixel 2^l i
        xy = pts.astype(np.float64) * 2.0**level
        out_xy.append(xy)
        out_level.append(np.full(len(xy), level, np.int64))
    if not out_xy:
        return Candidates(np.zeros((0, 2)), np.zeros(0, np.int64))
    cands = Candidates(np.concatenate(out_xy).reshape(-1, 2), np.concatenate(out_level))
    xy = cands.xy
    inside = ((xy[:, 0] >= BORDER_PX) & (xy[:, 0] <= W - 1 - BORDER_PX)
              & (xy[:, 1] >= BORDER_PX) & (xy[:, 1] <= H - 1 - BORDER_PX))
    cands = cands[inside]
    xi, yi = np.rint(cands.xy[:, 0]).astype(np.int64), np.rint(cands.xy[:, 1]).astype(np.int64)
    edge_distance = depth_edge_distance(frame.depth, float(frame.K[0, 0]), DEPTH_EDGE_STEP_FOOTPRINTS,
                                        fy=float(frame.K[1, 1]))
    keep = edge_distance[yi, xi] >= DEPTH_EDGE_MARGIN_PX  # on a pixel with depth, too
    return cands[keep]


def refine_peaks(response: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Sub-pixel positions of local maxima of `response` (H, W): a parabola through each peak and its
    two neighbours, along x and along y, offsets clipped to half a pixel.

    Args:
        response: (H, W) float32 cornerness map (the structure tensor's smaller eigenvalue).
        xy: (N, 2) peak positions on the pixel grid, pixels.
    Returns:
        (N, 2) float64 refined positions, pixels.

    This replaced OpenCV's cornerSubPix (the saddle point of the gradients in a window): on the
    validation sequences the parabola's positions were found again more often under deformation
    (repeatability 0.450 against 0.422, GeoPatch MS 0.318 against 0.294, same scorer).
    """
    H, W = response.shape
    x = np.clip(np.rint(xy[:, 0]).astype(np.int64), 1, W - 2)
    y = np.clip(np.rint(xy[:, 1]).astype(np.int64), 1, H - 2)
    centre = response[y, x].astype(np.float64)
    left, right = response[y, x - 1], response[y, x + 1]
    up, down = response[y - 1, x], response[y + 1, x]
    dx = np.clip((right - left) / (2.0 * np.maximum(2.0 * centre - left - right, 1e-12)), -0.5, 0.5)
    dy = np.clip((down - up) / (2.0 * np.maximum(2.0 * centre - up - down, 1e-12)), -0.5, 0.5)
    return np.stack([x + dx, y + dy], axis=1)


def suppress(xy: np.ndarray, score: np.ndarray, radius: float, shape: tuple[int, int]) -> np.ndarray:
    """(N,) bool: candidates whose score is the largest within `radius` pixels (of equal scores on
    one pixel, the first candidate only).

    The scores are splatted onto the pixel grid and compared with a grey dilation, so the cost is a
    few image operations whatever N is.
    """
    if len(xy) == 0 or radius <= 0:
        return np.ones(len(xy), bool)
    H, W = shape
    xi = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, W - 1)
    yi = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, H - 1)
    grid = np.full((H, W), -np.inf, np.float32)
    np.maximum.at(grid, (yi, xi), score.astype(np.float32))
    if radius >= np.hypot(H, W):  # every candidate within the radius of every other: the best one only
        peak = np.full_like(grid, grid.max())
    else:
        r = int(np.ceil(radius))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        peak = cv2.dilate(grid, kernel)
    keep = score.astype(np.float32) >= peak[yi, xi]
    kept = np.flatnonzero(keep)
    _, first = np.unique(yi[kept] * W + xi[kept], return_index=True)
    keep[:] = False
    keep[kept[first]] = True
    return keep


def detect_geokey(frame: RGBDFrame, n: int, model: GeoKeyModel | None = None,
                  nms_radius: float | None = None, mask: np.ndarray | None = None,
                  threshold: float | None = None, min_fraction: float | None = None,
                  denoise: float | None = None) -> Keypoints:
    """At most `n` GeoKey keypoints of `frame`, best first (0 = all that survive suppression and the
    threshold).

    Args:
        n: maximum number of keypoints (0 or None = all); fewer come back when fewer candidates reach
            `threshold`.
        model: the scorer (default: the shipped weights).
        nms_radius: suppression radius, pixels, >= 0 (default: the model's; 0 = no suppression).
        mask: (H, W), nonzero = allowed; restricts the keypoints like OpenCV's detection masks.
        threshold: minimum logit (default: the model's, chosen on validation; -inf keeps the `n` best
            whatever their score).
        min_fraction: the best this fraction of the candidates that survive suppression are kept
            whatever the threshold (default: the model's; 0 = none).
        denoise: range of the edge-preserving filter applied before detection, in multiples of the
            frame's noise level (default: the model's; 0 = none; `detection_image`).

    Returns `Keypoints` with angles 0 (GeoKey gives no orientation: geodesic descriptors are
    rotation-invariant), sizes 2^level x 8 px, and responses = the learned score (logit).
    A frame without depth or texture gives fewer keypoints, or none, with a warning.
    """
    n = _check_n(n, zero_is_all=True)
    model = model or load_geokey()
    nms_radius, threshold, min_fraction, denoise = check_settings(
        model.nms_radius if nms_radius is None else nms_radius, model.threshold if threshold is None else threshold,
        model.min_fraction if min_fraction is None else min_fraction, model.denoise if denoise is None else denoise)
    mask = None if mask is None else check_mask(mask, frame.shape)  # before any work
    raw_image = frame.image
    frame = detection_image(frame, denoise)
    cands = candidates(frame)
    if mask is not None:
        xi, yi = np.rint(cands.xy[:, 0]).astype(np.int64), np.rint(cands.xy[:, 1]).astype(np.int64)
        cands = cands[mask[yi, xi]]
    if len(cands) == 0:
        warnings.warn("geokey: no candidate with depth under it in this frame (no texture or no depth)", stacklevel=2)
        return Keypoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))
    score = model.score(candidate_features(frame, cands, depth_cues=model.uses_depth_cues))
    keep = suppress(cands.xy, score, nms_radius, frame.shape)
    cands, score = cands[keep], score[keep]
    order = np.argsort(-score, kind="stable")
    floor = int(min_fraction * len(order))
    reached = score[order] >= threshold
    order = order[(np.arange(len(order)) < floor) | reached]
    if len(order) == 0:
        warnings.warn(f"geokey: no candidate reaches the score threshold {threshold:g} in this frame "
                      "(little texture, or a view the detector does not trust)", stacklevel=2)
    elif not reached.any() and np.isfinite(threshold):  # a blank frame's noise: keypoints from the floor alone
        warnings.warn(f"geokey: no candidate reaches the score threshold {threshold:g} in this frame; its keypoints "
                      f"are only the floor of its best {100 * min_fraction:g} % of candidates (min_fraction): "
                      "little texture, or a view the detector does not trust", stacklevel=2)
    if n:
        order = order[:n]
    m = len(order)
    if reached.any():  # (the floor's own warning above covers a frame where none reached the threshold)
        share = noise_corner_share(raw_image, cands.xy[order])
        if share < NOISE_KEYPOINT_SHARE:
            warnings.warn(f"geokey: only {100 * share:.0f} % of this frame's keypoints are stronger corners than "
                          f"its image noise (noise level {noise_level(raw_image, NOISE_CHECK_STRIDE):.3g} of the image's range): little "
                          "texture; keypoints on noise are not found again in other views", stacklevel=2)
    return Keypoints(cands.xy[order], np.zeros(m), cands.size[order], score[order].astype(np.float64))


def candidate_features(frame: RGBDFrame, cands: Candidates, depth_cues: bool = True) -> np.ndarray:
    """(N, len(CUE_NAMES)) float32 cue features of the candidates (the scorer's input); without
    `depth_cues` (a scorer that does not read them) their columns are 0."""
    return cue_features(cue_maps(frame, depth_cues), cands.xy, cands.level)
