"""Matching score, as the authors' evaluation scripts compute it (see docs/concepts.md,
"Protocols"), on plain arrays.

Protocol "detect" (the paper's Table 1): keypoints detected independently in the reference and the
target frame; each target keypoint is mapped into the reference with the ground-truth deformation;
its nearest reference keypoint is its ground-truth partner when closer than 3 px (a reference
keypoint claimed by several target keypoints keeps the first in target order). One-way nearest
neighbour from every reference keypoint; a ground-truth pair (r, t) is a hit when r's nearest target
is t. MS = hits / min(n_ref, n_tgt); MMA = hits / number of ground-truth pairs.

Protocol "landmarks" (the GeoBit / GeoPatch scripts): descriptors at the csv landmarks; a landmark
visible in both frames is a query; a hit is a nearest neighbour with the same id.
Score = hits / landmarks visible in both frames.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay

from ..scoring import GT_THRESHOLD_PX, PairScore, ground_truth_pairs, score_detect, score_landmarks

__all__ = ["GT_THRESHOLD_PX", "LandmarkTPS", "PairScore", "authors_tps_warp", "ground_truth_pairs", "score_detect",
           "score_landmarks"]


class LandmarkTPS:
    """Thin-plate spline from target to reference pixels fitted to landmarks visible in both frames
    (scipy RBFInterpolator). Points outside the convex hull of the target landmarks map to NaN."""

    def __init__(self, tgt_xy: np.ndarray, ref_xy: np.ndarray, smoothing: float = 0.0) -> None:
        tgt_xy, ref_xy = np.asarray(tgt_xy, float), np.asarray(ref_xy, float)
        if len(tgt_xy) < 4:
            raise ValueError(f"landmarks: a thin-plate spline needs >= 4 landmarks visible in both frames, got {len(tgt_xy)}")
        self._rbf = RBFInterpolator(tgt_xy, ref_xy, kernel="thin_plate_spline", smoothing=smoothing)
        self._hull = Delaunay(tgt_xy)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        if len(xy) == 0:
            return np.zeros((0, 2))
        out = self._rbf(xy)
        out[self._hull.find_simplex(xy) < 0] = np.nan
        return out


def authors_tps_warp(xy: np.ndarray, theta: np.ndarray, ctrlpts: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The authors' published target->reference warp (`<k>_theta.npy`, `<k>_ctrlpts.npy`).

    Args:
        xy: (N, 2) target pixels. theta: (1, T+3, 2) or (T+3, 2) = [w (T, 2); a (3, 2)].
        ctrlpts: (T, 2) control points. size: (W, H) of the images (the TPS works in coordinates
            normalised by (W, H)).
    Returns:
        (N, 2) reference pixels: warped = p + [1, x, y] a + U w, U = d^2 log(d + 1e-6).
    """
    theta = np.asarray(theta, float).reshape(-1, 2)
    ctrl = np.asarray(ctrlpts, float).reshape(-1, 2)
    T = ctrl.shape[0]
    if theta.shape[0] != T + 3:
        raise ValueError(f"theta: expected {T + 3} rows for {T} control points, got {theta.shape[0]}")
    w, a = theta[:T], theta[T:]
    wh = np.asarray(size, float)
    p = np.asarray(xy, float).reshape(-1, 2) / wh
    d = np.linalg.norm(p[:, None, :] - ctrl[None, :, :], axis=-1)
    U = d**2 * np.log(d + 1e-6)
    affine = np.concatenate([np.ones((len(p), 1)), p], axis=1) @ a
    return (p + affine + U @ w) * wh
