"""Outlier rejection by local affine consistency, for surfaces that crumple.

RANSAC with one global model (`geofeat.apps.tracking.fit_tps_ransac`) keeps the matches of the largest
part of a surface that one smooth warp explains. When a cloth crumples into a ball, no smooth warp of
the whole template explains more than a part of it, and correct matches elsewhere are thrown away
(measured on the `hard` zoom-out sequences: RANSAC kept 118 of 236 correct matches in one frame).
A correct match, though, moves like its neighbours on the template: near any point a smooth surface
deformation seen by a camera is close to an affine map. `locally_consistent` keeps the matches that
the affine map of their own template neighbours predicts, found by a small RANSAC per match
(vectorised over all matches at once), in the spirit of locality-preserving matching (Ma et al.,
IJCV 2019) and of GMS (Bian et al., CVPR 2017).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..inputs import check_positive, check_whole
from ..tps import check_pairs, distinct_pairs

__all__ = ["locally_consistent", "NEIGHBOURS", "TRIALS", "LOCAL_TOLERANCE_PX"]

#: Template neighbours that vote on each match.
NEIGHBOURS = 12
#: Affine hypotheses (each from 3 of the neighbours) tried per match.
TRIALS = 24
#: A neighbour (and the match itself) agrees with a local affine map within this many frame pixels.
LOCAL_TOLERANCE_PX = 4.0


def locally_consistent(
    src: np.ndarray,
    dst: np.ndarray,
    neighbours: int = NEIGHBOURS,
    trials: int = TRIALS,
    tolerance_px: float = LOCAL_TOLERANCE_PX,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """Which matches agree with the local affine map of their template neighbours.

    For match i, its `neighbours` nearest matches on the template (i excluded) vote: `trials`
    affine maps, each through 3 of them chosen at random, are scored by how many of the neighbours
    they carry within `tolerance_px` of their frame positions; the best one must be supported by at
    least a third of the neighbours (and 3) and must carry match i itself within `tolerance_px`.
    Repeated matches (the same template and frame pixels, as SIFT's copies of one keypoint with
    another orientation often give) vote once, and share one verdict: a copy is no evidence.

    Args:
        src, dst: (N, 2) matched pixels, template and frame.
        neighbours: template neighbours per match, >= 3 (fewer when N is small).
        trials: affine hypotheses per match.
        tolerance_px: agreement radius, frame pixels.
        seed: random seed or generator (the result is deterministic for a given seed).
    Returns:
        (N,) bool, True for the matches that their neighbourhood confirms; all False when fewer than 8
        distinct matches.
    Raises:
        ValueError: src and dst are not two (N, 2) arrays of finite pixels; neighbours < 3, trials < 1
            or tolerance_px not a positive number.
    """
    src, dst = check_pairs(src, dst, 0)  # (N, 2) finite pixels each, or ValueError
    check_whole(neighbours, "neighbours", 3)  # an affine map needs 3 of them
    check_whole(trials, "trials", 1)
    check_positive(tolerance_px, "tolerance_px")
    src_d, dst_d, copy_of = distinct_pairs(src, dst)
    if copy_of is not None:  # repeated matches: judge each distinct one once
        return _locally_consistent(src_d, dst_d, neighbours, trials, tolerance_px, seed)[copy_of]
    return _locally_consistent(src, dst, neighbours, trials, tolerance_px, seed)


def _locally_consistent(src: np.ndarray, dst: np.ndarray, neighbours: int, trials: int, tolerance_px: float,
                        seed: int | np.random.Generator) -> np.ndarray:
    """`locally_consistent` on checked, distinct (N, 2) matches."""
    n = len(src)
    if n < 8:
        return np.zeros(n, bool)
    rng = np.random.default_rng(seed)
    k = min(neighbours, n - 1)
    _, nb = cKDTree(src).query(src, k + 1)
    # (N, k) template neighbours, i itself excluded: i is not always the first of its own k + 1 nearest,
    # since another match with the same template pixel (a SIFT copy matched elsewhere) ties with it at
    # distance 0; dropping column 0 then dropped that copy and kept i, whose hypotheses through itself
    # carried it exactly (random matches with shared template pixels were confirmed)
    others = nb != np.arange(n)[:, None]
    others[others.all(axis=1), -1] = False  # i beyond its k + 1 nearest (more copies than k): drop the last
    nb = nb[others].reshape(n, k)
    pick = np.argsort(rng.random((n, trials, k)), axis=2)[:, :, :3]  # (N, S, 3) three distinct neighbours
    trio = nb[np.arange(n)[:, None, None], pick]  # (N, S, 3) match indices
    P = np.concatenate([src[trio], np.ones(trio.shape + (1,))], axis=-1)  # (N, S, 3, 3) rows [x, y, 1]
    spans = np.abs(np.linalg.det(P)) > 1e-3  # three points not on a line (twice the triangle area, px^2)
    P[~spans] = np.eye(3)
    affine = np.linalg.solve(P, dst[trio])  # (N, S, 3, 2): [x, y, 1] @ affine = frame pixel
    homog = np.concatenate([src[nb], np.ones(nb.shape + (1,))], axis=-1)  # (N, k, 3)
    residual = np.linalg.norm(np.einsum("nkc,nscd->nskd", homog, affine) - dst[nb][:, None], axis=-1)
    support = (residual < tolerance_px).sum(axis=-1) * spans  # (N, S)
    best = np.argmax(support, axis=1)
    rows = np.arange(n)
    own = np.einsum("nc,ncd->nd", np.concatenate([src, np.ones((n, 1))], axis=1), affine[rows, best])
    return (np.linalg.norm(own - dst, axis=1) < tolerance_px) & (support[rows, best] >= max(3, k // 3))
