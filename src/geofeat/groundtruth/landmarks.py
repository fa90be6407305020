"""Splines through hand-clicked landmarks: `robust_landmark_tps` drops mislabelled landmarks by their
leave-one-out residual and fits the authors' spline (`geofeat.tps.authors_tps`) through the others;
`landmark_spline` is the target -> reference map of the bench's landmark ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

from ..inputs import as_points
from ..tps import AUTHORS_EPS, ThinPlateSpline, authors_tps, fit_tps, size_transform, system_matrix

__all__ = ["MIN_LANDMARKS", "RobustFit", "robust_landmark_tps", "landmark_spline", "inside_hull"]

#: Fewest landmarks a spline with an affine part needs (3 fix the affine part; one more bends it).
MIN_LANDMARKS = 4
#: A landmark is rejected when its leave-one-out residual exceeds this many pixels and
#: `OUTLIER_FACTOR` times the median leave-one-out residual of the others.
OUTLIER_MIN_PX = 8.0
OUTLIER_FACTOR = 4.0


@dataclass
class RobustFit:
    """A landmark spline with its inliers.

    Attributes:
        tps: the spline fitted to the inliers (the authors' parametrisation).
        inliers: (N,) bool over the landmarks given to `robust_landmark_tps`.
        loo_px: (N,) leave-one-out residual of each landmark in pixels (NaN for rejected ones): how far
            the spline fitted to the other inliers predicts it.
    """

    tps: ThinPlateSpline
    inliers: np.ndarray
    loo_px: np.ndarray


def _loo_residuals(src: np.ndarray, dst: np.ndarray, size) -> np.ndarray:
    """Leave-one-out residual (pixels) of each of the (T, 2) landmarks under an interpolating spline.

    For an interpolating spline the prediction of point i from the others follows from the inverse
    of the system matrix: residual_i = c_i / (L^-1)_ii with c = L^-1 rhs (the kernel weights)."""
    S = size_transform(size)
    scale = np.array([S[0, 0], S[1, 1]])
    c = src * scale
    T = len(c)
    Linv = np.linalg.pinv(system_matrix(c[None], 0.0, AUTHORS_EPS)[0])
    rhs = np.concatenate([dst * scale - c, np.zeros((3, 2))])
    w = (Linv @ rhs)[:T]
    diag = np.diag(Linv)[:T]
    return np.linalg.norm(w / np.where(np.abs(diag) > 1e-12, diag, np.nan)[:, None] / scale, axis=1)


def robust_landmark_tps(src: np.ndarray, dst: np.ndarray, size: tuple[int, int]) -> RobustFit:
    """Deformable-affine thin-plate spline src -> dst through landmarks, robust to a few mislabelled ones.

    The landmark with the largest leave-one-out residual is dropped while that residual exceeds both
    `OUTLIER_MIN_PX` and `OUTLIER_FACTOR` times the median of the others (at most a third of the
    landmarks are dropped); the spline then interpolates the remaining ones.

    Args:
        src, dst: (N, 2) landmark pixels in the source and destination images (same order).
        size: (W, H) image size, pixels.
    """
    src, dst = as_points(src, "src"), as_points(dst, "dst")
    if len(src) != len(dst):
        raise ValueError(f"src, dst: expected the same landmarks in both images, got {len(src)} and {len(dst)}")
    n = len(src)
    if n < MIN_LANDMARKS:
        raise ValueError(f"landmarks: a thin-plate spline needs >= {MIN_LANDMARKS} landmarks visible in both frames, got {n}")
    inliers = np.ones(n, bool)
    loo = np.full(n, np.nan)
    while True:
        idx = np.flatnonzero(inliers)
        # defined from MIN_LANDMARKS on (4 leave 3, whose affine map predicts the fourth); zeros here
        # reported a perfect leave-one-out fit for 4 landmarks
        r = _loo_residuals(src[idx], dst[idx], size)
        loo[:] = np.nan
        loo[idx] = r
        if len(idx) <= max(MIN_LANDMARKS + 2, int(np.ceil(2 * n / 3))) or not np.isfinite(r).all():
            break
        worst = int(np.argmax(r))
        others = np.delete(r, worst)
        if r[worst] <= max(OUTLIER_MIN_PX, OUTLIER_FACTOR * float(np.median(others))):
            break
        inliers[idx[worst]] = False
    return RobustFit(authors_tps(src[inliers], dst[inliers], size), inliers, loo)


def inside_hull(points: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(N,) bool: which of the (N, 2) pixels xy lie inside the convex hull of the (P, 2) pixels points.
    ValueError when the points are fewer than 3, collinear or repeated (a hull without inside)."""
    xy = as_points(xy, "xy")
    points = as_points(points, "points")
    if len(xy) == 0:
        return np.zeros(0, bool)
    try:
        return Delaunay(points).find_simplex(xy) >= 0
    except QhullError:
        raise ValueError(f"landmarks: the {len(points)} landmarks are collinear or repeated; their convex hull has "
                         "no inside, where a landmark spline could be trusted") from None


def landmark_spline(tgt_xy: np.ndarray, ref_xy: np.ndarray) -> ThinPlateSpline:
    """Interpolating spline from (L, 2) target landmark pixels to their (L, 2) reference pixels
    (Hartley-normalised, L >= `MIN_LANDMARKS`). Trust it only inside the landmarks' hull (`inside_hull`)."""
    if len(tgt_xy) < MIN_LANDMARKS:
        raise ValueError(f"landmarks: a thin-plate spline needs >= {MIN_LANDMARKS} landmarks visible in both frames, "
                         f"got {len(tgt_xy)}")
    return fit_tps(tgt_xy, ref_xy)
