"""Matching score, as the authors' evaluation scripts compute it (see
`shared/reference/matching_score_protocol.md`), on plain arrays.

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

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay, cKDTree

#: Ground-truth partner distance threshold, pixels (strictly less than).
GT_THRESHOLD_PX = 3.0


@dataclass
class PairScore:
    """Score of one (reference, target) pair."""

    ms: float
    mma: float
    hits: int
    n_ref: int
    n_tgt: int
    n_gt: int


def ground_truth_pairs(ref_xy: np.ndarray, tgt_in_ref: np.ndarray, threshold: float = GT_THRESHOLD_PX) -> np.ndarray:
    """Ground-truth pairs between reference keypoints and target keypoints mapped into the reference.

    Args:
        ref_xy: (n_ref, 2) reference keypoints, pixels.
        tgt_in_ref: (n_tgt, 2) target keypoints mapped into the reference image, pixels (NaN rows
            = no ground truth, never paired).
    Returns:
        (M, 2) int64 pairs (r, t), at most one per reference keypoint (the first t in target order).
    """
    ref_xy = np.asarray(ref_xy, float).reshape(-1, 2)
    tgt_in_ref = np.asarray(tgt_in_ref, float).reshape(-1, 2)
    if len(ref_xy) == 0 or len(tgt_in_ref) == 0:
        return np.zeros((0, 2), np.int64)
    ok = np.isfinite(tgt_in_ref).all(axis=1)
    dist, r = cKDTree(ref_xy).query(np.where(ok[:, None], tgt_in_ref, 0.0))
    t = np.flatnonzero(ok & (dist < threshold))
    r = r[t]
    _, first = np.unique(r, return_index=True)  # first target (in target order) for each r
    keep = np.sort(first)
    return np.stack([r[keep], t[keep]], axis=1).astype(np.int64)


def score_detect(matches0: np.ndarray, gt_pairs: np.ndarray, n_ref: int, n_tgt: int) -> PairScore:
    """MS and MMA of protocol "detect" from the reference->target nearest neighbours `matches0`
    (n_ref,) (-1 = none) and the ground-truth pairs (M, 2)."""
    gt_pairs = np.asarray(gt_pairs, np.int64).reshape(-1, 2)
    hits = int((np.asarray(matches0)[gt_pairs[:, 0]] == gt_pairs[:, 1]).sum()) if len(gt_pairs) else 0
    denom = min(n_ref, n_tgt)
    return PairScore(
        ms=hits / denom if denom else 0.0,
        mma=hits / len(gt_pairs) if len(gt_pairs) else 0.0,
        hits=hits, n_ref=int(n_ref), n_tgt=int(n_tgt), n_gt=int(len(gt_pairs)),
    )


def score_landmarks(matches0: np.ndarray, ref_ids: np.ndarray, tgt_ids: np.ndarray) -> PairScore:
    """Protocol "landmarks": `matches0` maps each visible reference landmark (ids `ref_ids`) to an
    index into the visible target landmarks (ids `tgt_ids`). A query is a reference landmark whose id
    is visible in the target; a hit is a nearest neighbour with the same id."""
    ref_ids, tgt_ids = np.asarray(ref_ids), np.asarray(tgt_ids)
    query = np.isin(ref_ids, tgt_ids)
    m = np.asarray(matches0)
    matched_ids = np.where(m >= 0, tgt_ids[np.clip(m, 0, max(len(tgt_ids) - 1, 0))] if len(tgt_ids) else -1, -1)
    hits = int((query & (matched_ids == ref_ids)).sum())
    n = int(query.sum())
    score = hits / n if n else 0.0
    return PairScore(ms=score, mma=score, hits=hits, n_ref=len(ref_ids), n_tgt=len(tgt_ids), n_gt=n)


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
