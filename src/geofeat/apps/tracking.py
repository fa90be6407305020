"""Deformable-surface tracking (the paper's second application, Table IV).

A template region of interest (ROI) of the reference frame is followed in every frame of a sequence:

1. keypoints (the 2048 best; `write_tracking`, what `geofeat track` runs, uses each descriptor's own
   detector by default, GeoKey for GeoPatch and GeoBit and SIFT for the others, while
   `track_sequence` uses one detector, SIFT unless told) of the reference frame, kept inside the
   ROI, are matched to the keypoints of frame k by mutual nearest descriptor distance
   (`geofeat.match`) and, once a frame has been fitted, also among the frame keypoints within
   `GUIDE_RADIUS_PX` of where the last good warp puts them (`guided_matches`); the match set whose
   fit keeps more RANSAC inliers is used;
2. a deformable-affine thin-plate spline (TPS) from template pixels to frame-k pixels is fitted with
   RANSAC outlier rejection (`fit_tps_ransac`), the template registered to frame k directly (no drift
   through frames). As in Tran et al., "In defence of RANSAC for outlier rejection in deformable
   registration" (ECCV 2012), both point sets are normalised first (centroid at the origin, mean
   distance sqrt(2)), hypotheses are TPS warps fitted to small random samples, and the best is refined
   on its inliers. A second fit starts instead from the matches that the local affine map of their
   template neighbours confirms (`fit_tps_local`, `geofeat.apps.localfit`), which keeps the correct
   matches of a crumpled cloth that no single global hypothesis explains; it replaces the RANSAC fit
   when it keeps at least 10 % more inliers;
3. per frame: matches, RANSAC inliers, inlier rate, the matching score of the kept matches (inliers
   that the bench's ground truth calls correct, over min(template, frame) keypoints as the bench's
   MS; and their precision, correct over the inliers that the ground truth covers), and the photometric
   similarity (SSIM, NCC) inside the ROI of the template and frame k warped back onto the template;
   a 10 x 10 grid over the ROI is carried into every frame by the fitted warp.
4. optionally (`refine="photometric"`), the spline is refined densely and photometrically against the
   template by the refiner of `geofeat groundtruth` (`geofeat.groundtruth.refine`: a B-spline
   displacement field on a 16 px control grid over the ROI's object pixels, L-BFGS coarse to fine on
   local NCC, the RANSAC inliers as soft landmarks). Every frame is registered to the template itself,
   from that frame's own spline, so errors cannot accumulate (no drift); the refined warp is kept only
   when it lowers the photometric cost and folds over at no more than `MAX_FOLDED_FRACTION` of its
   control points (`RefinedWarp`, `refine_warp`),
   otherwise the spline stays. The per-frame SSIM / NCC inside the ROI are the confidence.

Pixels follow the OpenCV convention (the centre of the top-left pixel is (0, 0)).
"""

from __future__ import annotations

import csv
import numbers
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from ..constants import N_KEYPOINTS
from ..inputs import as_points, check_positive, check_whole
from ..io import Sequence, frame_names, read_sequence, skipped_frame_line
from ..outputs import plural
from ..tps import (ThinPlateSpline, check_pairs, check_regularisation, distinct_pairs, evaluate_batch, normalise_points,
                   solve_batch)

if TYPE_CHECKING:
    from ..descriptors.describer import Describer
    from ..features import Features
    from ..frame import RGBDFrame
    from ..groundtruth.sources import GroundTruth
    from ..keypoints import Keypoints

__all__ = [
    "RansacResult", "TrackResult", "fit_tps_ransac", "fit_tps_local", "refit_on_inliers",
    "default_roi", "roi_grid", "similarity", "ncc", "ssim", "track_sequence", "write_tracking", "RefinedWarp",
    "refine_warp", "REFINE_MODES", "guided_matches",
]

#: RANSAC inlier threshold, pixels in the frame (the bench's 3 px correctness radius).
RANSAC_THRESHOLD_PX = 3.0
#: Correspondences per RANSAC hypothesis (a TPS through them; 3 would be a plain affine map).
RANSAC_SAMPLE_SIZE = 4
#: RANSAC hypotheses.
RANSAC_ITERATIONS = 1000
#: TPS smoothing of the refined warp, in normalised coordinates (`geofeat.tps.fit_tps`'s
#: regularisation; 0 = interpolate the inliers).
TPS_REGULARISATION = 1e-3
#: Most control points of the refined TPS (spread over the template).
MAX_CENTRES = 256
#: Fewest RANSAC inliers for a frame's fit to count as a success.
MIN_INLIERS = 10
#: Fewest template keypoints inside the ROI.
MIN_ROI_KEYPOINTS = 10
#: Grid side over the ROI (G = GRID_SIDE ** 2 points).
GRID_SIDE = 10
#: Dense refinement after RANSAC + TPS (`track_sequence(refine=...)`).
REFINE_MODES = ("none", "photometric")
#: A refined map is rejected when it folds over (Jacobian determinant <= 0) at more than this fraction
#: of the control points inside the ROI. A crumpled cloth hides parts of itself, so its true template ->
#: frame map does fold; 0.25 instead of `geofeat groundtruth`'s 0.05 let the refinement follow the
#: `hard` zoom-out sequences (visible-grid error 2.52 -> 1.38 px on scale-0) and changed nothing on
#: the other sequences (BENCHMARKS.md, "Crumpled cloth").
MAX_FOLDED_FRACTION = 0.25
#: `geofeat track --refine` default (chosen by grid error on simulated sequences, see BENCHMARKS.md).
DEFAULT_REFINE = "photometric"
#: L-BFGS iterations per pyramid level (finest first) of the tracking refinement: three times
#: `geofeat groundtruth`'s default, which stopped short of the optimum. Chosen on the four small
#: simulated sequences of BENCHMARKS.md ("More refinement iterations"); (10, 20, 30) / (20, 40, 60) /
#: (30, 60, 90) / (60, 120, 180) gave a mean visible-grid error of 0.59 / 0.56 / 0.55 / 0.55 px with
#: GeoKey + GeoPatch and 1.28 / 1.24 / 1.24 / 1.41 px with SIFT.
REFINE_ITERATIONS = (30, 60, 90)
#: The local-consistency fit (`fit_tps_local`) replaces the global RANSAC fit of a match set only when
#: it keeps this many times RANSAC's inliers: on a near tie the global, smoother model stays.
LOCAL_FIT_MARGIN = 1.1
#: Guided matching: a template keypoint's partner is searched among the frame's keypoints within
#: this many pixels of where the last successful warp puts it, pixels.
GUIDE_RADIUS_PX = 40.0


# ----------------------------------------------------------------------------------------------
# Thin-plate spline + RANSAC (the spline itself: `geofeat.tps`)


@dataclass
class RansacResult:
    """Outcome of `fit_tps_ransac`: warp (None when the fit failed) and inliers (N,) bool."""

    warp: ThinPlateSpline | None
    inliers: np.ndarray

    @property
    def ok(self) -> bool:
        return self.warp is not None


def _spread(points: np.ndarray, keep: np.ndarray, max_points: int) -> np.ndarray:
    """Indices of at most ~`max_points` of the `keep` (N,) bool points (N, 2), one per cell of a
    square grid over their bounding box (the first in index order), so that they cover it evenly."""
    idx = np.flatnonzero(keep)
    if len(idx) <= max_points:
        return idx
    p = points[idx]
    lo, hi = p.min(axis=0), p.max(axis=0)
    side = int(np.sqrt(max_points))
    cell = np.minimum(((p - lo) / np.maximum(hi - lo, 1e-12) * side).astype(np.int64), side - 1)
    _, first = np.unique(cell[:, 1] * side + cell[:, 0], return_index=True)
    return idx[np.sort(first)]


def _check_refit_counts(min_inliers: int, refinements: int, max_centres: int) -> None:
    """The counts of the refit: refinements 0 fitted nothing and max_centres under 4 spread the centres
    over a grid of one cell (one centre), so either reported every fit as failed without a word."""
    check_whole(min_inliers, "min_inliers", 0)
    check_whole(refinements, "refinements", 1)
    check_whole(max_centres, "max_centres", 4)


def fit_tps_ransac(
    src: np.ndarray,
    dst: np.ndarray,
    threshold_px: float = RANSAC_THRESHOLD_PX,
    sample_size: int = RANSAC_SAMPLE_SIZE,
    iterations: int = RANSAC_ITERATIONS,
    regularisation: float = TPS_REGULARISATION,
    min_inliers: int = MIN_INLIERS,
    refinements: int = 20,
    max_centres: int = MAX_CENTRES,
    seed: int | np.random.Generator = 0,
) -> RansacResult:
    """Robust TPS fit: RANSAC on small samples, then refinement on the inliers.

    Both point sets are normalised (`geofeat.tps.normalise_points`, as in Tran et al. ECCV 2012). Each
    of the `iterations` hypotheses is the TPS through `sample_size` random correspondences (fitted and
    scored in one batch by `geofeat.tps.solve_batch` / `evaluate_batch`); the one with most inliers (destination residual below
    `threshold_px` pixels) is refitted to its inliers with smoothing `regularisation` (through at
    most `max_centres` of them, spread over the template: one per cell of a grid), and inliers
    recomputed, up to `refinements` times or until they stop changing. Repeated matches (the same
    template and frame pixels) count once: as inliers, and towards `min_inliers`
    (`geofeat.tps.distinct_pairs`); each copy gets its pair's verdict.

    Args:
        src, dst: (N, 2) matched pixels, template and frame.
    Returns:
        `RansacResult`; warp is None (fit failed) when fewer than `min_inliers` distinct inliers remain or
        fewer than max(sample_size, min_inliers) distinct matches are given.
    """
    src, dst = check_pairs(src, dst, 0)
    for name, value in (("sample_size", sample_size), ("iterations", iterations)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise TypeError(f"{name}: expected an integer, got {value!r}")
    if sample_size < 3:
        raise ValueError(f"sample_size: expected >= 3 correspondences per hypothesis, got {sample_size}")
    check_whole(iterations, "iterations", 1)  # 0 or fewer tried nothing and reported a failed fit
    check_positive(threshold_px, "threshold_px")
    check_regularisation(regularisation)
    _check_refit_counts(min_inliers, refinements, max_centres)
    src_d, dst_d, copy_of = distinct_pairs(src, dst)
    if copy_of is not None:  # each copy counted as an inlier: 5 matches repeated 3 times passed min_inliers=10
        fit = fit_tps_ransac(src_d, dst_d, threshold_px, sample_size, iterations, regularisation, min_inliers,
                             refinements, max_centres, seed)
        return RansacResult(fit.warp, fit.inliers[copy_of])
    n = len(src)
    failed = RansacResult(None, np.zeros(n, bool))
    if n < max(sample_size, min_inliers, 3):
        return failed
    rng = np.random.default_rng(seed)
    _, sn = normalise_points(src)
    Td, dn = normalise_points(dst)
    thr = threshold_px * Td[0, 0]  # the threshold in normalised destination units
    best = np.zeros(n, bool)
    for start in range(0, iterations, 250):  # batches bound the (B, N, s) memory
        b = min(250, iterations - start)
        idx = np.argsort(rng.random((b, n)), axis=1)[:, :sample_size]  # (B, s) without replacement
        s_src, s_dst = sn[idx], dn[idx]
        w, a, ok = solve_batch(s_src, s_dst, 1e-9)
        pred = evaluate_batch(sn, s_src, w, a)
        inl = (((pred - dn[None]) ** 2).sum(-1) < thr**2) & ok[:, None]
        counts = inl.sum(axis=1)
        if counts.max() > best.sum():
            best = inl[np.argmax(counts)]
    return refit_on_inliers(src, dst, best, threshold_px, regularisation, min_inliers, refinements, max_centres)


def refit_on_inliers(
    src: np.ndarray,
    dst: np.ndarray,
    start: np.ndarray,
    threshold_px: float = RANSAC_THRESHOLD_PX,
    regularisation: float = TPS_REGULARISATION,
    min_inliers: int = MIN_INLIERS,
    refinements: int = 20,
    max_centres: int = MAX_CENTRES,
) -> RansacResult:
    """Fit the smoothing TPS to a first set of inliers and grow it: refit on the matches within
    `threshold_px` of the last fit, up to `refinements` times or until the set stops changing.

    Args:
        src, dst: (N, 2) matched pixels, template and frame.
        start: (N,) bool first inliers (RANSAC's best hypothesis, or `locally_consistent`'s matches).
    Returns:
        `RansacResult`; warp None when fewer than `min_inliers` distinct inliers remain (repeated
        matches count once, as in `fit_tps_ransac`).
    """
    src, dst = check_pairs(src, dst, 0)
    check_positive(threshold_px, "threshold_px")
    _check_refit_counts(min_inliers, refinements, max_centres)
    failed = RansacResult(None, np.zeros(len(src), bool))
    best = np.asarray(start, bool)
    if best.shape != (len(src),):
        raise ValueError(f"start: expected ({len(src)},) bool flags, one per match, got shape {best.shape}")
    src_d, dst_d, copy_of = distinct_pairs(src, dst)
    if copy_of is not None:  # a distinct match starts as an inlier when any of its copies does
        first = np.zeros(len(src_d), bool)
        np.logical_or.at(first, copy_of, best)
        fit = refit_on_inliers(src_d, dst_d, first, threshold_px, regularisation, min_inliers, refinements, max_centres)
        return RansacResult(fit.warp, fit.inliers[copy_of])
    if best.sum() < max(min_inliers, 3):
        return failed
    Ts, sn = normalise_points(src)
    Td, dn = normalise_points(dst)
    warp = None
    for _ in range(refinements):
        use = _spread(sn, best, max_centres)
        w, a, ok = solve_batch(sn[use][None], dn[use][None], regularisation)
        if not ok[0]:
            return failed
        warp = ThinPlateSpline(sn[use], w[0], a[0], Ts, Td)
        inliers = np.linalg.norm(warp(src) - dst, axis=1) < threshold_px
        if (inliers == best).all() or inliers.sum() < max(min_inliers, 3):
            break
        best = inliers
    if warp is None:
        return failed
    inliers = np.linalg.norm(warp(src) - dst, axis=1) < threshold_px  # the last fit's, not the set it was fitted to
    return RansacResult(warp, inliers) if inliers.sum() >= min_inliers else failed


def fit_tps_local(
    src: np.ndarray,
    dst: np.ndarray,
    threshold_px: float = RANSAC_THRESHOLD_PX,
    min_inliers: int = MIN_INLIERS,
    seed: int | np.random.Generator = 0,
) -> RansacResult:
    """Robust TPS fit for surfaces that one global RANSAC model cannot explain (a crumpled cloth):
    the matches that their template neighbours' local affine map confirms
    (`geofeat.apps.localfit.locally_consistent`) are the first inliers, then `refit_on_inliers`.
    The local maps' tolerance scales with `threshold_px` (4 px at the default 3 px), so that
    `geofeat track --threshold` reaches both steps, as its help says.

    Args:
        src, dst: (N, 2) matched pixels, template and frame.
    Returns:
        `RansacResult` (warp None when too few matches are confirmed).
    """
    from .localfit import LOCAL_TOLERANCE_PX, locally_consistent  # scipy.spatial: imported when first fitted

    src, dst = check_pairs(src, dst, 0)
    check_positive(threshold_px, "threshold_px")  # before the local fits
    tolerance = LOCAL_TOLERANCE_PX * threshold_px / RANSAC_THRESHOLD_PX
    return refit_on_inliers(src, dst, locally_consistent(src, dst, tolerance_px=tolerance, seed=seed), threshold_px,
                            min_inliers=min_inliers)


def guided_matches(features0, features1, predicted0: np.ndarray, radius: float = GUIDE_RADIUS_PX) -> np.ndarray:
    """Mutual nearest-neighbour matches restricted to a neighbourhood of a predicted position.

    Keypoint i of image 0 may match keypoint j of image 1 only if j lies within `radius` pixels of
    `predicted0[i]` (where the last good warp puts i); among those candidates the descriptor-nearest
    is taken, and kept only if i is in turn j's nearest among the image-0 keypoints that may match
    it. The search stays template -> frame (no drift): the prediction only narrows it.

    Args:
        features0, features1: `Features` of the template and the frame (same descriptor).
        predicted0: (N0, 2) predicted positions of image 0's keypoints in image 1, pixels (NaN rows:
            no prediction, never matched).
        radius: search radius, pixels.
    Returns:
        (N0,) int64 index into image 1's keypoints, -1 = no match.
    """
    from scipy.spatial.distance import cdist

    from ..matching import check_finite_descriptors, distance_matrix

    n0, n1 = len(features0.keypoints), len(features1.keypoints)
    predicted0 = np.asarray(predicted0, float)
    if predicted0.shape != (n0, 2):
        raise ValueError(f"predicted0: expected ({n0}, 2) pixels, one per keypoint of features0, got shape "
                         f"{predicted0.shape}")
    check_positive(radius, "radius")
    out = np.full(n0, -1, np.int64)
    if n0 == 0 or n1 == 0:
        return out
    check_finite_descriptors(features0.descriptors, features0.valid, "features0")
    check_finite_descriptors(features1.descriptors, features1.valid, "features1")
    dist = distance_matrix(features0.descriptors, features1.descriptors, valid0=features0.valid,
                           valid1=features1.valid).astype(np.float64)
    # (N0, N1) squared pixel distances; NaN predictions compare False, so they never match
    near = cdist(predicted0, np.asarray(features1.keypoints, float), "sqeuclidean") < radius**2
    allowed = near & features0.valid[:, None] & features1.valid[None, :]
    dist[~allowed] = np.inf
    best = np.argmin(dist, axis=1)
    back = np.argmin(dist, axis=0)
    ok = np.isfinite(dist[np.arange(n0), best]) & (back[best] == np.arange(n0))
    out[ok] = best[ok]
    return out


# ----------------------------------------------------------------------------------------------
# ROI, grid, similarity


def default_roi(mask: np.ndarray, shrink: float = 0.10) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) pixels: the bounding box of the (H, W) bool object mask shrunk by `shrink`
    of its width and height (half on each side), 0 <= shrink < 1."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask: expected an (H, W) object mask, got shape {mask.shape}")
    if isinstance(shrink, bool) or not isinstance(shrink, numbers.Real) or not 0 <= shrink < 1:
        raise ValueError(f"shrink: expected a fraction in [0, 1) of the mask's box, got {shrink!r}")
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        raise ValueError("mask: the object mask is empty; pass --roi x0,y0,x1,y1")
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    dx, dy = shrink * (x1 - x0) / 2, shrink * (y1 - y0) / 2
    return int(round(x0 + dx)), int(round(y0 + dy)), int(round(x1 - dx)), int(round(y1 - dy))


def check_roi(roi, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """Validate an (x0, y0, x1, y1) ROI against an image of shape (H, W)."""
    try:
        x0, y0, x1, y1 = (int(round(float(v))) for v in roi)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an infinite coordinate
        raise ValueError(f"roi: expected four numbers x0,y0,x1,y1 (pixels), got {roi!r}") from None
    H, W = shape
    if not (0 <= x0 < x1 <= W - 1 and 0 <= y0 < y1 <= H - 1):
        raise ValueError(f"roi: ({x0}, {y0}, {x1}, {y1}) is not a box inside the {W} x {H} image "
                         "(expected 0 <= x0 < x1 <= W-1 and 0 <= y0 < y1 <= H-1)")
    return x0, y0, x1, y1


def roi_grid(roi: tuple[int, int, int, int], side: int = GRID_SIDE) -> np.ndarray:
    """(side * side, 2) regular grid of pixels over the ROI, row-major (x fastest)."""
    x0, y0, x1, y1 = roi
    gx, gy = np.meshgrid(np.linspace(x0, x1, side), np.linspace(y0, y1, side))
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def ncc(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Zero-mean normalised cross-correlation of two images of the same shape over `mask` (read as
    bool, like `ssim`'s); NaN when the mask holds fewer than 2 pixels or either image is constant there."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    m = np.ones(a.shape, bool) if mask is None else np.asarray(mask, bool)  # a 0/1 mask would index rows 0 and 1
    if b.shape != a.shape or m.shape != a.shape:
        raise ValueError(f"a, b, mask: expected images and mask of one shape, got {a.shape}, {b.shape} and {m.shape}")
    if m.sum() < 2:
        return float("nan")
    x, y = a[m] - a[m].mean(), b[m] - b[m].mean()
    denom = np.sqrt((x * x).sum() * (y * y).sum())
    return float((x * y).sum() / denom) if denom > 0 else float("nan")


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM of two gray images in [0, 1] over `mask` (`geofeat.imagequality.mean_ssim`)."""
    from ..imagequality import mean_ssim

    return mean_ssim(a, b, mask)


@dataclass
class RefinedWarp:
    """A spline refined by a dense displacement field: p -> spline(p) + D(p), template -> frame pixels.

    Attributes:
        spline: the RANSAC TPS it refines.
        origin: (2,) pixel (x, y) of node [0, 0]; spacing: node spacing, pixels.
        coefficients: (Gy, Gx, 2) the refinement's cubic B-spline coefficients (`Refined.coefficients`),
            pixels: the warp is the very field whose photometric cost the refinement measured (a bilinear
            interpolation of its node values was another map, of a higher cost); zero from two spacings
            beyond the outermost nodes.
    """

    spline: ThinPlateSpline
    origin: np.ndarray
    spacing: float
    coefficients: np.ndarray

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        from ..groundtruth.photometric import _bspline_weights

        xy = as_points(xy, "xy")
        gy, gx = self.coefficients.shape[:2]
        wx = _bspline_weights(xy[:, 0], self.origin[0], self.spacing, gx).astype(np.float64)  # (M, Gx)
        wy = _bspline_weights(xy[:, 1], self.origin[1], self.spacing, gy).astype(np.float64)  # (M, Gy)
        d = np.stack([((wy @ self.coefficients[..., c]) * wx).sum(axis=1) for c in range(2)], axis=1)
        return self.spline(xy) + d


#: A fitted template -> frame warp: the RANSAC spline, or that spline refined photometrically.
Warp = ThinPlateSpline | RefinedWarp


def refine_warp(template: np.ndarray, image: np.ndarray, mask: np.ndarray, spline: ThinPlateSpline,
                lm_template: np.ndarray, lm_image: np.ndarray, roi: tuple[int, int, int, int],
                config=None) -> tuple["ThinPlateSpline | RefinedWarp", bool]:
    """Refine `spline` photometrically with `geofeat.groundtruth.refine` (template as the anchor).

    Args:
        template, image: (H, W) float32 gray images in [0, 1], template (reference) and frame.
        mask: (H, W) bool template pixels to register (the ROI's object pixels).
        spline: the RANSAC TPS, template -> frame pixels.
        lm_template, lm_image: (L, 2) RANSAC inlier pixels (soft landmarks).
        roi: (x0, y0, x1, y1): the fold-over test looks at the control points inside it.
        config: a `geofeat.groundtruth.RefineConfig` (None: its defaults with `REFINE_ITERATIONS`).
    Returns:
        (warp, accepted): the `RefinedWarp`, or `spline` itself when the refinement did not lower the
        photometric cost or folded the map over (Jacobian determinant <= 0 at more than
        MAX_FOLDED_FRACTION of the control points inside the ROI).
    """
    from ..groundtruth import RefineConfig, refine

    config = config if config is not None else RefineConfig(iterations=REFINE_ITERATIONS)
    r = refine(template, image, mask, spline, lm_template, lm_image, config)
    x0, y0, x1, y1 = roi
    n = r.nodes
    inside = (n[..., 0] >= x0) & (n[..., 0] <= x1) & (n[..., 1] >= y0) & (n[..., 1] <= y1)
    folded = float((r.jac_det[inside] <= 0).mean()) if inside.any() else 0.0
    if not r.cost < r.init_cost or folded > MAX_FOLDED_FRACTION:
        return spline, False
    spacing = float(n[0, 1, 0] - n[0, 0, 0]) if n.shape[1] > 1 else float(n[1, 0, 1] - n[0, 0, 1])
    return RefinedWarp(spline, n[0, 0].astype(np.float64), spacing, r.coefficients), True


def warp_back(image: np.ndarray, warp: "ThinPlateSpline | RefinedWarp", roi: tuple[int, int, int, int]
              ) -> tuple[np.ndarray, np.ndarray]:
    """Frame `image` (H, W) sampled at the warped template ROI pixels: returns the (h, w) float32
    image in template ROI coordinates and the (h, w) bool mask of pixels landing inside the frame."""
    x0, y0, x1, y1 = roi
    h, w = y1 - y0 + 1, x1 - x0 + 1
    # the warp is smooth: evaluate it every `step` pixels and interpolate bilinearly in between
    step = 4
    gx, gy = np.meshgrid(x0 + step * np.arange((w - 1) // step + 2.0), y0 + step * np.arange((h - 1) // step + 2.0))
    coarse = warp(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(gx.shape + (2,)).astype(np.float32)
    fx, fy = np.meshgrid(np.arange(w, dtype=np.float32) / step, np.arange(h, dtype=np.float32) / step)
    p = cv2.remap(coarse, fx, fy, cv2.INTER_LINEAR)  # (h, w, 2) frame pixels of the template ROI pixels
    H, W = image.shape
    inside = (p[..., 0] >= 0) & (p[..., 0] <= W - 1) & (p[..., 1] >= 0) & (p[..., 1] <= H - 1)
    out = cv2.remap(np.float32(image), p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return out, inside


def similarity(template: np.ndarray, image: np.ndarray, warp: "ThinPlateSpline | RefinedWarp | None",
               roi: tuple[int, int, int, int]) -> tuple[float, float]:
    """(SSIM, NCC) inside the ROI of the template (H, W) gray image and `image` warped back onto it;
    NaN when there is no warp."""
    if warp is None:
        return float("nan"), float("nan")
    x0, y0, x1, y1 = roi
    back, inside = warp_back(image, warp, roi)
    crop = np.float32(template[y0 : y1 + 1, x0 : x1 + 1])
    return ssim(crop, back, inside), ncc(crop, back, inside)


# ----------------------------------------------------------------------------------------------
# Sequences


@dataclass
class TrackResult:
    """Tracking of one sequence with one descriptor.

    Attributes:
        sequence, descriptor: names.
        roi: (x0, y0, x1, y1) template ROI, reference pixels.
        frames: the F frame names, reference first.
        reference_points: (G, 2) grid over the ROI, reference pixels.
        points: (F, G, 2) where the fitted warps put the grid in each frame (frame 0 = the grid
            itself), NaN where the fit failed.
        rows: one dict per target frame (see `TRACK_COLUMNS`).
        mask_source: where the object mask came from ("simulator", "objmask", "depth").
        skipped: target frames that could not be read or described (a failed row with NaN figures, so
            that they count as lost; points stay NaN).
        depth_profile: the depth profile the sequence was described with ("kinect", "quantised", "clean").
        setup_seconds: wall time of the template's set-up (reading the sequence, detecting and describing
            the reference frame, loading the ground truth), shared by the descriptors tracked together.
    """

    sequence: str
    descriptor: str
    roi: tuple[int, int, int, int]
    frames: list[str]
    reference_points: np.ndarray
    points: np.ndarray
    rows: list[dict] = field(default_factory=list)
    mask_source: str = ""
    skipped: list[str] = field(default_factory=list)
    depth_profile: str = ""
    setup_seconds: float = 0.0


#: Columns of track.csv. n_template / n_frame: keypoints in the template ROI / in the frame; matches:
#: template keypoints with a nearest neighbour; inliers: RANSAC inliers among them; ms: correct
#: inliers / min(n_template, n_frame) (the bench's matching score applied to the kept matches);
#: precision: correct inliers / inliers that the ground truth covers (NaN when it covers none; correct: the bench's ground truth within 3 px, `geofeat.scoring.correct_matches`);
#: grid_error_px: median over the grid (its points on the object in the reference) of |ground truth(tracked point) - grid point|, reference pixels
#: (a tracked point the ground truth maps nowhere left out, or lost (inf) when the simulator sees its grid point in the frame, `_grid_error`);
#: grid_error_tps_px: the same for the RANSAC spline alone (before refinement); grid_error_visible_px:
#: median over the grid points seen in the frame of |tracked point - true position|, frame pixels
#: (simulated sequences only: the forward ground truth); visible_grid: the fraction of the grid seen
#: in the frame. grid_error_px maps the tracked point back through the ground truth, so a grid point
#: hidden under a fold is scored at the surface that covers it, however well it is tracked;
#: grid_error_visible_px leaves hidden points out. refined: the refined
#: warp was kept; ssim, ncc: the frame's confidence, template vs frame warped back inside the ROI;
#: seconds: this descriptor's matching, RANSAC, refinement and confidence for the frame (a failed fit:
#: its matching and RANSAC; NaN only for a frame that could not be read or described).
#: A failed (or skipped) frame's grid errors are inf (lost) where the sequence's ground truth measures them,
#: NaN where it has none.
TRACK_COLUMNS = ["sequence", "descriptor", "frame", "n_template", "n_frame", "matches", "inliers", "inlier_rate",
                 "ms", "precision", "ssim", "ncc", "grid_error_px", "grid_error_tps_px", "grid_error_visible_px",
                 "visible_grid", "refined", "seconds", "failed"]


def sequence_radius(seq: Sequence, radius: float | None) -> float:
    """Geodesic radius in metres: `radius`, else the sequence's (geofeat.json, else 0.075), as the bench
    (`geofeat.inputs.resolve_radius`, the one rule)."""
    from ..inputs import resolve_radius

    return resolve_radius(radius, seq)


def track_sequence(
    folder: str | Path,
    descriptors: tuple[str, ...] = ("geopatch", "geobit", "sift"),
    roi: tuple[int, int, int, int] | None = None,
    n_keypoints: int = N_KEYPOINTS,
    tps_dir: str | None = None,
    radius: float | None = None,
    depth_scale: float | None = None,
    threshold_px: float = RANSAC_THRESHOLD_PX,
    seed: int = 0,
    progress: bool = True,
    refine: str = DEFAULT_REFINE,
    detector: str = "sift",
    device: str | None = None,
) -> dict[str, TrackResult]:
    """Track the template ROI of a sequence's reference frame through all its frames.

    The outline: `_Template.build` (the sequence, ROI, template keypoints and descriptors, ground
    truth); per target frame, its keypoints and descriptors (`_Template.describe_frame`) and, per
    descriptor, `_track_frame` (matching, RANSAC spline, optional refinement, the frame's row).

    Args:
        folder: a sequence in the public layout (reference frame + targets).
        descriptors: names known to `geofeat.make_descriptor`.
        roi: (x0, y0, x1, y1) reference pixels; None = the object mask's bounding box shrunk by 10 %.
        n_keypoints: keypoints per frame (the best).
        detector: keypoint detector, as in `geofeat.detect` ("sift", "geokey", "geokey=WEIGHTS").
        tps_dir: the authors' TPS ground truth (object masks, and ground truth for the scores).
        radius: geodesic radius in metres (None: the sequence's geofeat.json or 0.075).
        threshold_px: RANSAC inlier threshold, pixels.
        refine: "none" (the RANSAC spline) or "photometric" (`refine_warp` on the ROI's object pixels).
        device: None or "cpu": every descriptor on the CPU; "cuda" / "cuda:N": GeoPatch described on
            that GPU (`Describer`) and its mutual matches searched there (`geofeat.match(..., device=)`;
            the guided matches stay on the CPU), the other descriptors on the CPU
            (`geofeat.gpu.gpu_descriptors`: ValueError when none of `descriptors` is GeoPatch).
    Returns:
        {descriptor: TrackResult}. Frames whose fit fails are recorded as failed; the run goes on.
    """
    from ..descriptors import check_descriptor_names
    from ..gpu import gpu_descriptors

    names = check_descriptor_names(descriptors)  # unknown or repeated names fail before any work
    gpu_descriptors(names, device)  # a device that is not one, or that no descriptor would use
    if refine not in REFINE_MODES:
        raise ValueError(f"refine: expected one of {', '.join(REFINE_MODES)}, got {refine!r}")
    check_positive(threshold_px, "threshold")  # NaN or inf would fail every frame, or pass every match
    t_setup = time.perf_counter()
    template = _Template.build(folder, names, roi, n_keypoints, tps_dir, radius, depth_scale, detector, device)
    t_setup = time.perf_counter() - t_setup
    seq = template.seq
    results = {name: template.new_result(name) for name in names}
    for r in results.values():
        r.setup_seconds = t_setup
    prior: dict[str, Warp | None] = {name: None for name in names}  # each descriptor's last good warp
    bar = tqdm(list(enumerate(seq.targets, start=1)), desc=f"track {seq.name}", unit="frame", disable=not progress)
    for k, frame_name in bar:
        try:
            frame, keypoints, features = template.describe_frame(frame_name, n_keypoints, detector)
        except ValueError as error:  # reported by name; the other frames go on
            tqdm.write(skipped_frame_line(frame_name, error, seq.name))
            for name, r in results.items():
                r.skipped.append(frame_name)
                # a failed row: the frame counts as lost, as a failed fit does. Without it a detector that
                # found nothing on a frame (GeoKey on a frame without depth) left the frame out of its
                # descriptor's figures, while another detector's failed fit on it counted as lost
                r.rows.append(_skipped_row(template, frame_name, name))
            continue
        target = _Target(frame_name, frame, keypoints, features, template.to_reference(frame_name, keypoints.xy),
                         template.truth.project(frame_name, template.grid) if template.truth is not None else None)
        for name in names:
            row, warp, points = _track_frame(template, target, name, prior[name], refine, threshold_px, seed)
            if warp is not None:
                prior[name] = warp
                results[name].points[k] = points
            results[name].rows.append(row)
    return results


def _template_roi(seq: Sequence, roi, tps_dir: str | None = None
                 ) -> tuple["RGBDFrame", tuple[int, int, int, int], np.ndarray, str]:
    """The template of `seq`: its reference frame, the checked (x0, y0, x1, y1) ROI (`roi`, or None for
    `default_roi` of the object mask), the (H, W) bool object mask and its source (`object_mask`).
    ValueError naming the sequence when the reference frame cannot be read, its object mask is empty
    (no ROI given) or the ROI is not a box inside it."""
    from .objectmask import object_mask

    try:
        ref = seq.frame(seq.reference)
    except ValueError as error:  # named: a run over several sequences stops at this one
        raise ValueError(f"sequence {seq.name}: the reference frame {seq.reference} cannot be used "
                         f"({str(error).splitlines()[0]})") from None
    mask, mask_source = object_mask(seq, seq.reference, tps_dir)
    try:
        return ref, check_roi(default_roi(mask) if roi is None else roi, ref.shape), mask, mask_source
    except ValueError as error:  # one --roi for sequences of several sizes: say which one it misses
        raise ValueError(f"{error} (sequence {seq.name}, reference frame {seq.reference})") from None


def _warn_if_undescribed(sequence: str, descriptor: str, described: int, total: int,
                         roi: tuple[int, int, int, int]) -> None:
    """Warn when `descriptor` described fewer of the `total` template keypoints than a fit keeps
    (`MIN_INLIERS`): every frame then fails for it, which the tables showed as lost frames without a
    reason (FREAK drops the keypoints near the image border, so a ROI along it left none)."""
    if described < MIN_INLIERS:
        warnings.warn(f"sequence {sequence}: {descriptor} describes {described} of the {total} template keypoints "
                      f"in the ROI {roi} (it drops keypoints too near the image border, or without what it needs "
                      f"there); a fit keeps at least {MIN_INLIERS} matches, so every frame will fail for "
                      f"{descriptor}: move the ROI inward or choose another descriptor", UserWarning, stacklevel=2)


@dataclass
class _Template:
    """What stays fixed while one sequence is tracked.

    Attributes:
        seq: the sequence.
        frame: its reference frame (the template).
        roi: (x0, y0, x1, y1) template ROI, reference pixels.
        roi_mask: (H, W) bool pixels the photometric refinement registers: the ROI's object pixels
            (the whole ROI when the object mask misses most of it).
        mask_source: where the object mask came from ("simulator", "objmask", "depth").
        keypoints: the N template keypoints (inside the ROI).
        features: {descriptor: `Features` of the N template keypoints}.
        describe: the `Describer` of every frame (one mesh and one set of patches for all descriptors).
        grid: (G, 2) regular grid over the ROI, reference pixels.
        truth: the sequence's `GroundTruth`, None when it has none (no scores then).
        depth_profile: the depth profile of `describe` (`sequence_depth_profile`).
    """

    seq: Sequence
    frame: "RGBDFrame"
    roi: tuple[int, int, int, int]
    roi_mask: np.ndarray
    mask_source: str
    keypoints: "Keypoints"
    features: dict[str, "Features"]
    describe: "Describer"
    grid: np.ndarray
    truth: "GroundTruth | None"
    depth_profile: str = ""

    @classmethod
    def build(cls, folder: str | Path, names: tuple[str, ...], roi: tuple[int, int, int, int] | None,
              n_keypoints: int, tps_dir: str | None, radius: float | None, depth_scale: float | None,
              detector: str, device: str | None = None) -> "_Template":
        """Read the sequence, choose and check the ROI, detect and describe the template keypoints
        inside it, and load the ground truth (arguments as `track_sequence`'s)."""
        from ..depth import sequence_depth_profile
        from ..descriptors.describer import Describer
        from ..groundtruth.sources import GroundTruth
        from ..keypoints import detect

        seq = read_sequence(folder, depth_scale=depth_scale)
        if len(seq) < 2:
            raise ValueError(f"sequence {seq.name}: needs a reference frame and at least one other frame, got {len(seq)} frame(s)")
        ref, roi, mask, mask_source = _template_roi(seq, roi, tps_dir)
        x0, y0, x1, y1 = roi
        keypoints = detect(ref, n_keypoints, detector=detector)
        inside = ((keypoints.xy[:, 0] >= x0) & (keypoints.xy[:, 0] <= x1)
                  & (keypoints.xy[:, 1] >= y0) & (keypoints.xy[:, 1] <= y1))
        keypoints = keypoints[inside]
        if len(keypoints) < MIN_ROI_KEYPOINTS:
            # keypoints need depth: say so when the ROI has little, not only that it holds no keypoints
            with_depth = float((ref.depth[y0 : y1 + 1, x0 : x1 + 1] > 0).mean())
            if n_keypoints is not None and n_keypoints < MIN_ROI_KEYPOINTS:  # not the ROI's fault
                raise ValueError(f"keypoints: {n_keypoints} per frame, fewer than the {MIN_ROI_KEYPOINTS} a template "
                                 "needs in its ROI; ask for more (the frame's best are kept, then those in the ROI)")
            raise ValueError(f"roi: {roi} holds {len(keypoints)} keypoints of {seq.reference}; expected at least "
                             f"{MIN_ROI_KEYPOINTS}" + (f" (only {with_depth:.0%} of its pixels have depth, and a keypoint "
                                                       "needs depth)" if with_depth < 0.5 else ""))
        try:
            truth = GroundTruth(seq, tps_dir)
        except ValueError:
            if tps_dir is not None:  # TPS files asked for but none for this sequence: it lost its scores without a
                raise                # word, even those of its simulator or landmark ground truth
            truth = None
        profile = sequence_depth_profile(seq, None, ref)
        describe = Describer(names, sequence_radius(seq, radius), profile, device=device)
        features = {name: f for name, (f, _) in describe(ref, keypoints).items()}
        for name, f in features.items():
            _warn_if_undescribed(seq.name, name, int(np.count_nonzero(f.valid)), len(keypoints), roi)
        roi_mask = np.zeros(ref.shape, bool)
        roi_mask[y0 : y1 + 1, x0 : x1 + 1] = True
        if (roi_mask & mask).sum() >= 0.25 * roi_mask.sum():  # the object's pixels, unless the mask misses the ROI
            roi_mask &= mask
        return cls(seq, ref, roi, roi_mask, mask_source, keypoints, features, describe, roi_grid(roi), truth, profile)

    def describe_frame(self, name: str, n_keypoints: int, detector: str) -> tuple["RGBDFrame", "Keypoints", dict[str, "Features"]]:
        """Read frame `name`, detect its N1 keypoints and describe them with every descriptor:
        (frame, keypoints, {descriptor: Features}). ValueError when the frame cannot be read or
        described or holds no keypoint (the caller skips it)."""
        from ..keypoints import detect

        frame = self.seq.frame(name)
        keypoints = detect(frame, n_keypoints, detector=detector)
        if len(keypoints) == 0:
            raise ValueError("no keypoints detected")
        return frame, keypoints, {d: f for d, (f, _) in self.describe(frame, keypoints).items()}

    def to_reference(self, name: str, xy: np.ndarray) -> np.ndarray | None:
        """(N, 2) pixels of frame `name` mapped into the reference by the ground truth, NaN rows where
        it is unknown; None when the sequence has no ground truth, or none for this frame (said on the
        console): TPS files that leave it out (`geofeat groundtruth` writes none for a frame that
        failed), or too few landmarks seen in both frames, or collinear ones, for a landmark spline.
        (Either stopped the whole run with a message that did not name the frame.)"""
        if self.truth is None:
            return None
        reason = self.truth.uncovered_reason(name)
        if reason is not None:
            tqdm.write(f"{self.seq.name}: no ground truth for {name} ({reason}); its ground-truth figures are NaN")
            return None
        try:
            return self.truth.map(name, xy)[0]
        except ValueError as error:
            if self.truth.tps is not None or self.truth.exact:  # not a landmark spline of this frame: a real error
                raise
            tqdm.write(f"{self.seq.name}: no ground truth for {name} ({str(error).splitlines()[0]}); its "
                       "ground-truth figures are NaN")
            return None

    def new_result(self, descriptor: str) -> TrackResult:
        """An empty `TrackResult`: the grid in the reference frame, NaN points elsewhere, no rows."""
        points = np.full((len(self.seq), len(self.grid), 2), np.nan)
        points[0] = self.grid
        return TrackResult(self.seq.name, descriptor, self.roi, list(self.seq.names), self.grid, points,
                           mask_source=self.mask_source, depth_profile=self.depth_profile)


@dataclass
class _Target:
    """One target frame, described once for all descriptors.

    Attributes:
        name: the frame's name in the sequence.
        frame: the frame.
        keypoints: its N1 keypoints.
        features: {descriptor: `Features` of the N1 keypoints}.
        to_ref: (N1, 2) the keypoints mapped into the reference by the ground truth, pixels (NaN rows
            where it is unknown); None when the sequence has no ground truth.
        grid_truth: (xy (G, 2), visible (G,)) where the template grid truly lies in this frame and
            which of its points are seen there (`GroundTruth.project`); None without the simulator's
            forward ground truth.
    """

    name: str
    frame: "RGBDFrame"
    keypoints: "Keypoints"
    features: dict[str, "Features"]
    to_ref: np.ndarray | None
    grid_truth: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class _Fit:
    """The matches of one frame that were kept and their RANSAC spline.

    Attributes:
        i0, i1: (M,) int64 template and frame keypoint indices of the M matches.
        ransac: the RANSAC fit to them (`ransac.inliers`: (M,) bool).
    """

    i0: np.ndarray
    i1: np.ndarray
    ransac: RansacResult


def _match_and_fit(template: _Template, target: _Target, name: str, prior: Warp | None,
                   threshold_px: float, seed: int) -> _Fit:
    """Match the template to the frame with descriptor `name` and fit a robust spline: mutual nearest
    neighbours and, once a previous frame was fitted (`prior`), also matches searched near where that
    warp puts each template keypoint (`guided_matches`); each match set is fitted by global RANSAC
    (`fit_tps_ransac`) and by local affine consistency (`fit_tps_local`; used when it keeps
    `LOCAL_FIT_MARGIN` times RANSAC's inliers), and the match set whose fit keeps more inliers wins
    (the first on a tie)."""
    from ..matching import match

    f0, f1 = template.features[name], target.features[name]
    options = [match(f0, f1, mutual=True, device=template.describe.match_device(name)).matches0]
    if prior is not None:
        options.append(guided_matches(f0, f1, prior(template.keypoints.xy)))
    best = None
    for matches0 in options:
        i0 = np.flatnonzero(matches0 >= 0)
        i1 = matches0[i0]
        src, dst = template.keypoints.xy[i0], target.keypoints.xy[i1]
        fit = fit_tps_ransac(src, dst, threshold_px=threshold_px, seed=seed)
        local = fit_tps_local(src, dst, threshold_px=threshold_px, seed=seed)
        if local.inliers.sum() > LOCAL_FIT_MARGIN * fit.inliers.sum():
            fit = local
        if best is None or fit.inliers.sum() > best.ransac.inliers.sum():
            best = _Fit(i0, i1, fit)
    return best


def _skipped_row(template: _Template, frame: str, name: str) -> dict:
    """The track.csv row of a target frame that could not be read or described: failed, no
    keypoints or matches (inlier rate 0, as a failed fit without matches), the other figures NaN and
    the grid errors lost (`_lost_errors`)."""
    row = {key: float("nan") for key in TRACK_COLUMNS}
    row.update(sequence=template.seq.name, descriptor=name, frame=frame, n_template=len(template.keypoints),
               n_frame=0, matches=0, inliers=0, inlier_rate=0.0, refined=False, failed=True)
    truth = template.truth
    row.update(_lost_errors(truth is not None, truth is not None and truth.exact))
    return row


def _lost_errors(backward: bool, forward: bool) -> dict:
    """The grid errors of a failed frame: inf (lost) for those the sequence's ground truth measures
    (`backward`: frame -> reference, grid_error_px; `forward`: the simulator's, grid_error_visible_px),
    NaN for the others, so that a table does not call a frame "lost" by a measure it never had."""
    lost = lambda known: np.inf if known else float("nan")  # noqa: E731
    return dict(grid_error_px=lost(backward), grid_error_tps_px=lost(backward), grid_error_visible_px=lost(forward))


def _track_frame(template: _Template, target: _Target, name: str, prior: Warp | None, refine: str,
                 threshold_px: float, seed: int) -> tuple[dict, Warp | None, np.ndarray | None]:
    """One descriptor on one target frame: match, fit, optionally refine, and measure.

    Returns:
        (row, warp, points): the frame's row of track.csv (`TRACK_COLUMNS`); the warp, template ->
        frame pixels, and (G, 2) where it puts the grid, frame pixels; both None when the fit failed.
    """
    t0 = time.perf_counter()
    fit = _match_and_fit(template, target, name, prior, threshold_px, seed)
    n_inliers = fit.ransac.inliers.sum()
    row = dict(sequence=template.seq.name, descriptor=name, frame=target.name, n_template=len(template.keypoints),
               n_frame=len(target.keypoints), matches=len(fit.i0), inliers=int(n_inliers),
               inlier_rate=n_inliers / len(fit.i0) if len(fit.i0) else 0.0, ms=float("nan"),
               precision=float("nan"), ssim=float("nan"), ncc=float("nan"), grid_error_px=float("nan"),
               grid_error_tps_px=float("nan"), grid_error_visible_px=float("nan"), visible_grid=float("nan"),
               refined=False, seconds=float("nan"), failed=not fit.ransac.ok)
    if not fit.ransac.ok:
        row["seconds"] = time.perf_counter() - t0  # its matching and RANSAC: a failure costs time too
        # lost where the ground truth could have scored it (inf), NaN where there is none to score it by
        row.update(_lost_errors(target.to_ref is not None, target.grid_truth is not None))
        if target.grid_truth is not None:
            row["visible_grid"] = float(target.grid_truth[1].mean())
        return row, None, None
    kept0, kept1 = fit.i0[fit.ransac.inliers], fit.i1[fit.ransac.inliers]  # the inliers' keypoint indices
    warp = fit.ransac.warp
    if refine == "photometric":
        warp, row["refined"] = refine_warp(template.frame.image, target.frame.image, template.roi_mask, warp,
                                           template.keypoints.xy[kept0], target.keypoints.xy[kept1], template.roi)
    points = warp(template.grid)
    row["ssim"], row["ncc"] = similarity(template.frame.image, target.frame.image, warp, template.roi)
    row["seconds"] = time.perf_counter() - t0
    if target.to_ref is not None:
        row.update(_truth_figures(template, target, fit, warp, points))
    return row, warp, points


def _truth_figures(template: _Template, target: _Target, fit: _Fit, warp: Warp, points: np.ndarray) -> dict:
    """The ground-truth columns of a fitted frame's row: ms and precision of the RANSAC inliers
    (correct: `geofeat.scoring.correct_matches`, the bench's 3 px rule; precision over the inliers whose
    frame keypoint has ground truth, NaN when none has), and the grid errors of the
    final warp (`points`: (G, 2) frame pixels) and of the RANSAC spline alone, reference pixels."""
    from ..scoring import correct_matches

    kept = fit.ransac.inliers
    in_ref = target.to_ref[fit.i1[kept]]
    correct = int(correct_matches(template.keypoints.xy[fit.i0[kept]], in_ref).sum())
    # precision over the inliers the ground truth can judge: one off the landmarks' hull or under a
    # fold is unscored, not wrong (counting it wrong gave 0.77 on a frame identical to the reference)
    scored = int(np.isfinite(in_ref).all(axis=1).sum())
    truth, grid = template.truth, template.grid
    grid_error = _grid_error(truth, target.name, points, grid, target.grid_truth)
    visible_error, visible_fraction = _visible_grid_error(target.grid_truth, points)
    return dict(
        ms=correct / max(min(len(template.keypoints), len(target.keypoints)), 1),
        precision=correct / scored if scored else float("nan"),
        grid_error_px=grid_error,
        grid_error_tps_px=(grid_error if warp is fit.ransac.warp
                           else _grid_error(truth, target.name, fit.ransac.warp(grid), grid, target.grid_truth)),
        grid_error_visible_px=visible_error,
        visible_grid=visible_fraction,
    )


def _grid_error(truth, target: str, pts: np.ndarray, grid: np.ndarray,
                grid_truth: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Median over the (G, 2) grid of |ground truth(tracked (G, 2) frame pixels) - grid point|, pixels,
    over the grid points on the object in the reference (`GroundTruth.reference_keep`): a grid point
    off the object (an ROI corner on the background) has no true position, and one whose tracked point
    landed on the object was scored against an unrelated part of it (the visible-points error leaves
    them out too). A tracked point that the ground truth maps nowhere is left out, unless `grid_truth`
    (`_Target.grid_truth`, the simulator's) says its grid point is seen in the frame: its true position
    then maps back onto it, so the tracked point is elsewhere, and it counts as lost (inf). (Left out,
    a warp that threw grid points onto the background scored better than one that tracked them a few
    pixels off.)"""
    g = np.linalg.norm(truth.map(target, pts)[0] - grid, axis=1)
    if grid_truth is not None:
        g[np.isnan(g) & np.asarray(grid_truth[1], bool)] = np.inf
    g[~np.asarray(truth.reference_keep(grid), bool)] = np.nan
    return float(np.nanmedian(g)) if (~np.isnan(g)).any() else float("nan")


def _visible_grid_error(grid_truth: tuple[np.ndarray, np.ndarray] | None, pts: np.ndarray) -> tuple[float, float]:
    """(error, fraction): the median over the grid points seen in the frame of |tracked point (G, 2)
    - where the point truly is|, frame pixels, and the fraction of the grid seen there; NaN for both
    without the forward ground truth (`grid_truth`: `_Target.grid_truth`)."""
    if grid_truth is None:
        return float("nan"), float("nan")
    xy, visible = grid_truth
    error = np.linalg.norm(pts[visible] - xy[visible], axis=1)
    return (float(np.median(error)) if len(error) else float("nan")), float(visible.mean())


def _draw_grid(image: np.ndarray, pts: np.ndarray, side: int, colour) -> tuple[np.ndarray, bool]:
    """(picture, drawn): a copy of the (H, W, 3) uint8 BGR `image` with the (side * side, 2) grid
    `pts` (frame pixels) drawn in `colour`; drawn False (nothing drawn) when the fit failed (a NaN point)."""
    out = image.copy()
    if not np.isfinite(pts).all():
        return out, False
    g = np.round(pts.reshape(side, side, 2) * 4).astype(np.int32)  # 2 fractional bits
    for line in list(g) + list(g.transpose(1, 0, 2)):
        cv2.polylines(out, [np.ascontiguousarray(line.reshape(-1, 1, 2))], False, colour, 2, cv2.LINE_AA, shift=2)
    return out, True


#: `track.gif`'s widest frame, pixels (`grid_frames`).
MAX_GIF_WIDTH = 960


def grid_frames(seq: Sequence, result: TrackResult, scale: float = 0.5,
                max_width: int | None = MAX_GIF_WIDTH) -> list[np.ndarray]:
    """(h, w, 3) uint8 RGB pictures of every frame with the tracked grid drawn (the template's in
    blue, the others in green), resized by `scale`, or by less where that leaves them wider than
    `max_width` pixels (None: no limit; 4000-pixel frames made a GIF of 2000-pixel frames), each
    labelled with the descriptor and the frame name at a legible size whatever `scale`. A frame in `result.skipped` (it could not be read or
    described) gets a dark placeholder that says so, so that the animation keeps every frame's place."""
    from ..viz import put_label, to_bgr

    pictures = []
    shape = None  # (H, W) of the frames read
    for k, name in enumerate(result.frames):
        if name in result.skipped:
            pictures.append(name)  # drawn below, once a readable frame gave the size
            continue
        bgr = to_bgr(seq.frame(name))
        shape = bgr.shape[:2]
        if max_width is not None:
            scale = min(scale, max_width / shape[1])
        pic, drawn = _draw_grid(bgr, result.points[k], GRID_SIDE, (0, 255, 0) if k else (255, 200, 0))
        if scale != 1:
            pic = cv2.resize(pic, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        put_label(pic, f"{result.descriptor}  {name}" + ("" if drawn else " (fit failed)"), (4, 4), 0.45)
        pictures.append(cv2.cvtColor(pic, cv2.COLOR_BGR2RGB))
    if shape is None:  # the template is always read, so this is a result without frames
        return [p for p in pictures if not isinstance(p, str)]
    for k, p in enumerate(pictures):
        if isinstance(p, str):
            h, w = max(1, round(shape[0] * scale)), max(1, round(shape[1] * scale))
            pic = np.full((h, w, 3), 40, np.uint8)
            put_label(pic, f"{result.descriptor}  {p} (skipped: not read or described)", (4, 4), 0.45)
            pictures[k] = cv2.cvtColor(pic, cv2.COLOR_BGR2RGB)
    return pictures


def _mean(values) -> float:
    """Mean of the non-NaN values (an inf, a lost sequence, makes it inf), NaN when there is none."""
    v = np.asarray([x for x in values], float)
    v = v[~np.isnan(v)]
    return float(v.mean()) if len(v) else float("nan")


def _was_skipped(row: dict) -> bool:
    """A row of a frame that could not be read or described (`_skipped_row`): failed, and no keypoint
    of the frame (a failed fit on a described frame has its keypoints)."""
    return _failed(row) and int(float(row["n_frame"])) == 0 and np.isnan(float(row["seconds"]))


def _failed(row: dict) -> bool:
    return str(row["failed"]) in ("True", "1")


def failed_rows(csv_path: str | Path) -> tuple[int, int]:
    """(failed, total) rows of a `track.csv` (one row per sequence, descriptor and target frame):
    those whose frame was not tracked (its fit failed, or the frame could not be read or described),
    and all of them."""
    with open(csv_path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return sum(_failed(r) for r in rows), len(rows)


def _lost_median(rows: list[dict], key: str, measured: bool = True) -> float:
    """Median of column `key` over `rows` (one sequence and descriptor), a failed frame counted as
    lost (an infinite error, so that failing never scores better than a poor fit); NaN when the
    sequence has no ground truth for `key` (`measured` False: `_measured`)."""
    if not measured:
        return float("nan")
    return _median(np.inf if _failed(r) else _value(r, key) for r in rows)


def _measured(rows: list[dict], key: str) -> bool:
    """Whether column `key` was measured on these rows (one sequence, every descriptor): some row
    holds a value (a failed frame's inf included); all NaN: the sequence has no ground truth for it."""
    return any(not np.isnan(_value(r, key)) for r in rows)


def _value(row: dict, key: str) -> float:
    """Column `key` of a track row as a float; NaN when absent or empty."""
    v = row.get(key)
    return float("nan") if v is None or v == "" else float(v)


def _cell(value: float, digits: int = 2) -> str:
    """A table cell: "lost" for inf, "–" for NaN, else the value."""
    return "lost" if value == np.inf else "–" if not np.isfinite(value) else f"{value:.{digits}f}"


def tracking_table(rows: list[dict]) -> str:
    """Markdown table like the paper's Table IV: per descriptor, each metric averaged per sequence
    (over its target frames), then over sequences. A failed frame counts in the inlier rate (with the
    inliers its failed RANSAC kept), but its matching score, precision, SSIM and NCC are NaN and left
    out of the means: a failure does not lower them, so read them beside the failed-frames column. The
    grid errors are medians per sequence in which a failed frame counts as lost (an infinite error,
    so that failing never scores better than a poor fit), then averaged over sequences ("lost" when
    a sequence lost half of its frames or more)."""
    names = list(dict.fromkeys(r["descriptor"] for r in rows))
    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    lines = ["| descriptor | inlier rate | matching score | precision | SSIM | NCC | grid error (reference px, median) "
             "| grid error, visible points (frame px, median) | failed frames |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        per = {key: [] for key in ("inlier_rate", "ms", "precision", "ssim", "ncc", "grid_error_px", "grid_error_visible_px")}
        failed = total = 0
        for s in seqs:
            sel = [r for r in rows if r["descriptor"] == name and r["sequence"] == s]
            if not sel:
                continue
            for key in ("inlier_rate", "ms", "precision", "ssim", "ncc"):
                per[key].append(_mean(float(r[key]) for r in sel))
            for key in ("grid_error_px", "grid_error_visible_px"):
                per[key].append(_lost_median(sel, key, _measured([r for r in rows if r["sequence"] == s], key)))
            failed += sum(_failed(r) for r in sel)
            total += len(sel)
        lines.append(f"| {name} | {_cell(_mean(per['inlier_rate']))} | {_cell(_mean(per['ms']))} | {_cell(_mean(per['precision']))} | "
                     f"{_cell(_mean(per['ssim']))} | {_cell(_mean(per['ncc']))} | {_cell(_mean(per['grid_error_px']), 1)} | "
                     f"{_cell(_mean(per['grid_error_visible_px']), 1)} | "
                     f"{failed}/{total} |")
    return "\n".join(lines) + "\n"


def sequence_error_table(rows: list[dict], key: str = "grid_error_visible_px") -> str:
    """Markdown table of the median grid error per sequence (rows) and descriptor (columns), pixels,
    a failed frame counted as lost (infinite), as in `tracking_table`; "" when `rows` has no `key`
    (a sequence without simulator ground truth)."""
    names = list(dict.fromkeys(r["descriptor"] for r in rows))
    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    if not _measured(rows, key):
        return ""
    lines = ["| sequence | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for s in seqs:
        cells = []
        measured = _measured([r for r in rows if r["sequence"] == s], key)
        for name in names:
            sel = [r for r in rows if r["descriptor"] == name and r["sequence"] == s]
            cells.append(_cell(_lost_median(sel, key, measured)) if sel else "–")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: The paper's Table IV (Potje et al., CVIU 2022): inlier rate of RANSAC, matching score and LPIPS,
#: averaged over its sequences DeSurT, Kinect 1 and Simulation (real data not shipped here). "*":
#: the descriptor's own keypoints; None: not reported.
PAPER_TABLE_IV = {
    "dali": (0.32, 0.31, 0.45), "delf*": (0.25, None, 0.40), "logpolar": (0.36, 0.36, 0.33),
    "r2d2*": (0.48, None, 0.36), "tfeat": (0.31, 0.37, 0.29), "geobit": (0.46, 0.42, 0.27),
    "geopatch": (0.49, 0.45, 0.29),
}


def paper_table_iv(names) -> str:
    """The rows of the paper's Table IV for the descriptors in `names` (its TFeat and Log-Polar for
    ours trained on the simulator, "tfeat-sim" and "logpolar-sim"), Markdown; "" when none is there."""
    def key(name: str) -> str:
        return name.removesuffix("-sim")

    rows = [(n, PAPER_TABLE_IV[key(n)]) for n in names if key(n) in PAPER_TABLE_IV]
    if not rows:
        return ""
    fmt = lambda v: "–" if v is None else f"{v:.2f}"  # noqa: E731
    lines = ["The paper's Table IV, for comparison (its sequences DeSurT, Kinect 1 and Simulation, not these; "
             "LPIPS, lower is better, is not computed here):", "",
             "| descriptor | inlier rate | matching score | LPIPS |", "|---|---|---|---|"]
    lines += [f"| {n} (paper) | {fmt(a)} | {fmt(b)} | {fmt(c)} |" for n, (a, b, c) in rows]
    return "\n".join(lines) + "\n"


def _median(values) -> float:
    """Median of the non-NaN values (inf counts: a lost frame), NaN when there is none."""
    v = np.asarray([x for x in values], float)
    v = v[~np.isnan(v)]
    return float(np.median(v)) if len(v) else float("nan")


def _frame_rate(n_frames: int, seconds: float) -> str:
    """Frames per second as printed in tracking.md: three significant figures, never in exponent form
    ("0.00943", "4", "12.3"). Two decimals printed a CPU run with refinement (0.003-0.03 frames/s) as
    "0.00" or "0.01", a rate off by up to half of itself or zero."""
    return np.format_float_positional(n_frames / max(seconds, 1e-9), precision=3, unique=False,
                                      fractional=False, trim="-")


def _result_folder(descriptor: str) -> str:
    """The folder of a descriptor's results under OUT/<sequence>/ ("geopatch=w.pt" -> "geopatch_w.pt")."""
    return descriptor.replace("=", "_").replace("/", "_")


def write_tracking(sequences, out: str | Path, descriptors: tuple[str, ...], roi=None, n_keypoints: int = N_KEYPOINTS,
                   tps_dir: str | None = None, radius: float | None = None, depth_scale: float | None = None,
                   threshold_px: float = RANSAC_THRESHOLD_PX, progress: bool = True,
                   overwrite: bool = False, skipped: list[str] | None = None,
                   refine: str = DEFAULT_REFINE, detector: str | None = None,
                   device: str | None = None) -> tuple[Path, str]:
    """Track every sequence with every descriptor and write into `out`:
    `track.csv` (one row per sequence, descriptor and target frame), per sequence and descriptor
    `<sequence>/<descriptor>/grid.npz` (reference_points (G, 2), points (F, G, 2), frames (F,),
    roi (4,)) and `<sequence>/<descriptor>/track.gif`, and `tracking.md` (the averaged table, and
    the speed: target frames per second of wall time, every descriptor included (the templates' set-up timed apart), and each
    descriptor's mean seconds per frame for matching, RANSAC, refinement and SSIM/NCC, failed fits included).
    The folder is built aside and moved into place at the end (`geofeat.outputs`); an existing
    non-empty `out` needs `overwrite`. Frames that could not be described are listed in
    `tracking.md` and appended as "sequence/frame" to `skipped` when a list is given. `detector`:
    the keypoints of every descriptor, or None for each descriptor's own (`keypoints.detector_for`:
    GeoKey for GeoPatch and GeoBit, SIFT for the others); descriptors with the same detector are
    tracked together (`track_sequence`). `device`: "cuda" / "cuda:N" tracks GeoPatch on that GPU and
    the other descriptors on the CPU (`track_sequence`), said in `tracking.md`. Returns the csv path and
    the table."""
    import imageio.v2 as imageio

    from ..descriptors import check_descriptor_names
    from ..groundtruth.sources import tps_folder
    from ..inputs import check_tps_dir
    from ..io import find_sequences, path_list
    from ..keypoints import group_by_detector
    from ..gpu import gpu_descriptors
    from ..outputs import check_out_dir, output_folder

    names = check_descriptor_names(descriptors)  # unknown or repeated names fail before any work
    on_gpu = gpu_descriptors(names, device)  # before any work, as the names
    folders: dict[str, str] = {}
    for name in names:  # "geopatch=a/w.pt" and "geopatch=a_w.pt" wrote one folder, the second's results over the first's
        other = folders.setdefault(_result_folder(name), name)
        if other != name:
            raise ValueError(f"descriptors: {other!r} and {name!r} would write their results into one folder, "
                             f"{_result_folder(name)!r}; rename one weights file")
    groups = group_by_detector(names, detector)
    given, sequences = path_list(sequences), find_sequences(sequences, unique_names=True)
    # every file at a fixed name, per sequence and descriptor too: a user's file there was found only when
    # the results were moved into place, after all the tracking
    files = ["track.csv", "tracking.md"] + [f"{Path(folder).name}/{_result_folder(name)}/{file}" for folder in sequences
                                            for name in names for file in ("grid.npz", "track.gif")]
    out = check_out_dir(out, overwrite, files=files, inputs=[*given, *sequences, tps_dir])
    check_tps_dir(tps_dir)
    for folder in sequences:  # before any work: a sequence of one frame found after hours of tracking lost them all
        count = len(frame_names(folder))
        if count < 2:
            raise ValueError(f"sequence {Path(folder).name}: needs a reference frame and at least one other frame, "
                             f"got {count} frame(s)")
        if tps_dir is not None and tps_folder(tps_dir, Path(folder).name) is None:  # `_Template.build` refuses it
            raise ValueError(f"tps-dir: no TPS files (<frame>_theta.npy, <frame>_objmask.png) for sequence "
                             f"{Path(folder).name} in {Path(tps_dir) / Path(folder).name} or "
                             f"{Path(tps_dir)}/*/{Path(folder).name}")
        # the reference frame and the ROI of every sequence, before any work: a --roi outside a later
        # sequence's smaller frames, or its unreadable reference, ended the run after the earlier
        # sequences were tracked, and their results were thrown away
        _template_roi(read_sequence(folder, depth_scale=depth_scale), roi, tps_dir)
    rows: list[dict] = []
    notes = []
    seconds = setup = 0.0
    with output_folder(out) as tmp:
        with open(tmp / "track.csv", "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, TRACK_COLUMNS)
            writer.writeheader()
            for folder in sequences:
                t0 = time.perf_counter()
                results, skipped_here = {}, []
                for det, group in groups.items():
                    part = track_sequence(folder, group, roi=roi, n_keypoints=n_keypoints, tps_dir=tps_dir,
                                          radius=radius, depth_scale=depth_scale, threshold_px=threshold_px,
                                          progress=progress, refine=refine, detector=det,
                                          device=device if set(group) & set(on_gpu) else None)
                    results.update(part)
                    setup += next(iter(part.values())).setup_seconds
                    skipped_here += [f for f in next(iter(part.values())).skipped if f not in skipped_here]
                results = {name: results[name] for name in names}  # the order asked for
                seconds += time.perf_counter() - t0
                seq = read_sequence(folder, depth_scale=depth_scale)
                for name, r in results.items():
                    writer.writerows(r.rows)
                    rows.extend(r.rows)
                    sub = tmp / seq.name / _result_folder(name)
                    sub.mkdir(parents=True, exist_ok=True)
                    np.savez(sub / "grid.npz", reference_points=r.reference_points, points=r.points,
                             frames=np.array(r.frames), roi=np.array(r.roi))
                    imageio.mimsave(sub / "track.gif", grid_frames(seq, r), duration=400, loop=0)
                first = next(iter(results.values()))
                if skipped is not None:
                    skipped.extend(f"{first.sequence}/{f}" for f in skipped_here)
                # the template frame by name: a sequence whose frames have no `master`/`ref` name is tracked
                # from its first frame in sorted order, which the notes did not say
                notes.append(f"{first.sequence}: template frame {first.frames[0]}, ROI {first.roi}, "
                             f"object mask from {first.mask_source}, "
                             f"depth profile {first.depth_profile}"
                             + (f"; SKIPPED frames: {', '.join(skipped_here)}" if skipped_here else ""))
        table = tracking_table(rows)
        # frames/s over the frames tracked: a skipped frame (not read or described) has a row, a failed
        # one, but no tracking was timed on it, and counting it raised the rate
        n_skipped = len({(r["sequence"], r["frame"]) for r in rows if _was_skipped(r)})
        n_frames = len({(r["sequence"], r["frame"]) for r in rows}) - n_skipped
        per = ", ".join(f"{n} {_mean(float(r['seconds']) for r in rows if r['descriptor'] == n):.3f} s"
                        for n in dict.fromkeys(r["descriptor"] for r in rows))
        of = {name: det for det, group in groups.items() for name in group}
        detectors = ", ".join(f"{name}: {of[name]}" for name in names)
        # the templates' set-up is timed apart: with few target frames it dominated the rate
        tracked = max(seconds - setup, 0.0)
        notes.append(f"detector: {detectors}; refine: {refine}; {plural(n_frames, 'target frame')} tracked in {tracked:.1f} s: "
                     f"{_frame_rate(n_frames, tracked)} frames/s (reading, detection, description and every "
                     f"descriptor; the templates' set-up, {setup:.1f} s, not counted"
                     + (f"; {plural(n_skipped, 'skipped frame')} not counted" if n_skipped else "") + "); "
                     f"per frame, matching + RANSAC{' + refinement' if refine != 'none' else ''} + SSIM/NCC: {per}"
                     + (f"; {', '.join(on_gpu)} described and matched on {device}, the others on the CPU" if on_gpu else ""))
        paper = paper_table_iv(dict.fromkeys(r["descriptor"] for r in rows))
        per_sequence = sequence_error_table(rows)
        if per_sequence:
            per_sequence = ("Grid error of the visible points per sequence (median over target frames, frame "
                            "pixels; a failed frame is lost):\n\n" + per_sequence)
        (tmp / "tracking.md").write_text(table + ("\n" + paper if paper else "")
                                         + ("\n" + per_sequence if per_sequence else "") + "\n"
                                         + "\n".join(f"- {n}" for n in notes) + "\n", encoding="utf-8")
    return out / "track.csv", table
