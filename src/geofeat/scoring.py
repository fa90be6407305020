"""Matching score of one image pair from nearest-neighbour matches and ground-truth pairs, as the
authors' evaluation scripts compute it (see docs/concepts.md, "Protocols"), on plain
arrays. Shared by the benchmark and the training loop's validation (so it lives below both).

Protocol "detect": each target keypoint mapped into the reference with the ground truth; its nearest
reference keypoint is its ground-truth partner when closer than 3 px (a reference keypoint claimed
by several target keypoints keeps the first in target order). A ground-truth pair (r, t) is a hit
when r's nearest target is t. MS = hits / min(n_ref, n_tgt); MMA = hits / number of ground-truth pairs.

Protocol "landmarks": a landmark visible in both frames is a query; a hit is a nearest neighbour
with the same id. Score = hits / landmarks visible in both frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .inputs import as_points

__all__ = ["GT_THRESHOLD_PX", "PairScore", "correct_matches", "ground_truth_pairs", "score_detect", "score_landmarks"]

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
    ref_xy, tgt_in_ref = as_points(ref_xy, "ref_xy"), as_points(tgt_in_ref, "tgt_in_ref")
    if len(ref_xy) == 0 or len(tgt_in_ref) == 0:
        return np.zeros((0, 2), np.int64)
    ok = np.isfinite(tgt_in_ref).all(axis=1)
    dist, r = cKDTree(ref_xy).query(np.where(ok[:, None], tgt_in_ref, 0.0))
    t = np.flatnonzero(ok & (dist < threshold))
    r = r[t]
    _, first = np.unique(r, return_index=True)  # first target (in target order) for each r
    keep = np.sort(first)
    return np.stack([r[keep], t[keep]], axis=1).astype(np.int64)


def correct_matches(ref_xy: np.ndarray, tgt_in_ref: np.ndarray, threshold: float = GT_THRESHOLD_PX) -> np.ndarray:
    """Which of M given matches are correct: the target keypoint, mapped into the reference with the
    ground truth, lies closer than `threshold` pixels to the reference keypoint it was matched to.

    The per-match form of the 3 px rule of `ground_truth_pairs`, for matches that were filtered
    after matching (tracking's RANSAC inliers); it does not ask that the reference keypoint be the
    nearest one.

    Args:
        ref_xy: (M, 2) reference keypoints of the matches, pixels.
        tgt_in_ref: (M, 2) their target keypoints mapped into the reference image, pixels (NaN rows
            = no ground truth, never correct).
    Returns:
        (M,) bool.
    """
    ref_xy, tgt_in_ref = as_points(ref_xy, "ref_xy"), as_points(tgt_in_ref, "tgt_in_ref")
    if len(ref_xy) != len(tgt_in_ref):
        raise ValueError(f"tgt_in_ref: expected one point per match, {len(ref_xy)} like ref_xy, got {len(tgt_in_ref)}")
    return np.linalg.norm(tgt_in_ref - ref_xy, axis=1) < threshold


def _check_matches0(matches0, n_ref: int, n_tgt: int, ref_name: str, tgt_name: str) -> np.ndarray:
    """`matches0` as an (n_ref,) int64 array of target indices in [-1, n_tgt): a shorter one gave an
    IndexError, an index past the targets counted as a match to the last one, and n_ref other than
    the matches' count an MS above 1. ValueError naming the argument otherwise."""
    for name, value in ((ref_name, n_ref), (tgt_name, n_tgt)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name}: expected a keypoint count >= 0, got {value!r}")
    m = np.asarray(getattr(matches0, "matches0", matches0))  # a `Matches` record reads as its matches0
    if m.shape != (n_ref,) or (m.size and m.dtype.kind not in "iu"):
        raise ValueError(f"matches0: expected ({ref_name}={n_ref},) integer indices of the nearest target, one "
                         f"per reference keypoint, got {m.dtype} shape {m.shape}")
    if m.size and (m.min() < -1 or m.max() >= n_tgt):
        raise ValueError(f"matches0: expected target indices in [0, {tgt_name}={n_tgt}) or -1 (no match), got "
                         f"values from {m.min()} to {m.max()}")
    return m.astype(np.int64)


def score_detect(matches0: np.ndarray, gt_pairs: np.ndarray, n_ref: int, n_tgt: int) -> PairScore:
    """MS and MMA of protocol "detect" from the reference->target nearest neighbours `matches0`
    (n_ref,) (-1 = none; a `Matches` reads as its matches0) and the ground-truth pairs (M, 2) of
    `ground_truth_pairs`. ValueError when their lengths or indices do not fit n_ref and n_tgt."""
    m = _check_matches0(matches0, n_ref, n_tgt, "n_ref", "n_tgt")
    gt_pairs = np.asarray(gt_pairs)
    if gt_pairs.size == 0:
        gt_pairs = np.zeros((0, 2), np.int64)
    if gt_pairs.ndim != 2 or gt_pairs.shape[1] != 2 or gt_pairs.dtype.kind not in "iu":
        raise ValueError(f"gt_pairs: expected (M, 2) integer pairs (r, t) from `ground_truth_pairs`, got "
                         f"{gt_pairs.dtype} shape {gt_pairs.shape}")
    if len(gt_pairs) and ((gt_pairs < 0).any() or gt_pairs[:, 0].max() >= n_ref or gt_pairs[:, 1].max() >= n_tgt):
        raise ValueError(f"gt_pairs: indices must lie in [0, n_ref={n_ref}) and [0, n_tgt={n_tgt}), got reference "
                         f"{gt_pairs[:, 0].min()}..{gt_pairs[:, 0].max()} and target {gt_pairs[:, 1].min()}.."
                         f"{gt_pairs[:, 1].max()}")
    hits = int((m[gt_pairs[:, 0]] == gt_pairs[:, 1]).sum()) if len(gt_pairs) else 0
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
    ref_ids, tgt_ids = np.asarray(ref_ids).reshape(-1), np.asarray(tgt_ids).reshape(-1)
    m = _check_matches0(matches0, len(ref_ids), len(tgt_ids), "len(ref_ids)", "len(tgt_ids)")
    query = np.isin(ref_ids, tgt_ids)
    matched_ids = np.where(m >= 0, tgt_ids[np.clip(m, 0, max(len(tgt_ids) - 1, 0))] if len(tgt_ids) else -1, -1)
    hits = int((query & (matched_ids == ref_ids)).sum())
    n = int(query.sum())
    score = hits / n if n else 0.0
    return PairScore(ms=score, mma=score, hits=hits, n_ref=len(ref_ids), n_tgt=len(tgt_ids), n_gt=n)
