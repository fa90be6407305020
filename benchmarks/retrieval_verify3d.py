"""Re-ranking retrieval results by 3D-verified matches, against the local affine check of the command.

An RGB-D frame gives every keypoint a 3D point, and a surface that bends without stretching keeps
the distances between nearby surface points; a camera that moves back keeps them too. So a match
can be verified by its neighbours' distances, in metres, instead of by a local affine map in pixels
(`geofeat.apps.localfit.locally_consistent`, what `geofeat retrieval --rerank` uses). This script
measures whether that ranks better, on frames cached by `retrieval_weightings.py --cache`.

For each descriptor: the words' top `--depth` results per query (K words, `tfidf-l1`, vocabulary
seed 0, as the command), mutual matches with Lowe's ratio 0.9 per (query, frame) pair (the
command's), then three scores of the pair: the matches the affine check keeps (the command's
score), the matches the 3D check keeps (`metric_consistent`), and their sum. Prints mean Acc@1-10
on the validation half, the test half and all queries (`split_queries(..., 0)`, the command's split).

    python benchmarks/retrieval_verify3d.py --cache /tmp/big2_geokey.pkl --descriptors geopatch@geokey
    python benchmarks/retrieval_verify3d.py --cache /tmp/big2.pkl --descriptors sift
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from common import cached_retrieval, word_shortlist
from scipy.spatial import cKDTree
from tqdm import tqdm

from geofeat.apps.localfit import locally_consistent
from geofeat.apps.retrieval import RERANK, RERANK_RATIO, per_query_accuracy
from geofeat.depth import backproject
from geofeat.io import read_sequence
from geofeat.matching import match

#: Neighbours (nearest matches in 3D, on the query side) that vote on each match.
NEIGHBOURS = 12
#: A neighbour agrees when its distance to the match changes by less than max(ABS_M, REL x distance).
ABS_M, REL = 0.005, 0.2
#: Neighbours closer than this (on either side) carry no information (SIFT's duplicate keypoints) and do not vote.
MIN_DISTANCE_M = 0.01


def keypoint_points(db, features) -> list[np.ndarray]:
    """(N_i, 3) camera-frame points, metres, of every frame's keypoints (depth at the nearest pixel;
    NaN where there is none)."""
    points, seqs = [], {}
    for folder, name, f in tqdm(list(zip(db.folders, db.frames, features)), desc="3D points", unit="frame"):
        seq = seqs.get(folder) or seqs.setdefault(folder, read_sequence(folder))
        frame = seq.frame(name)
        H, W = frame.shape
        xi = np.clip(np.rint(f.keypoints[:, 0]).astype(np.int64), 0, W - 1)
        yi = np.clip(np.rint(f.keypoints[:, 1]).astype(np.int64), 0, H - 1)
        points.append(backproject(frame.depth, frame.K)[yi, xi])
    return points


def metric_consistent(P: np.ndarray, Q: np.ndarray, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """(N,) bool: matches (P[i] in the query, Q[i] in the frame, (N, 3) metres) whose distances to
    their `neighbours` nearest matches (in P) agree in Q for at least a third of them (and 3)."""
    ok = np.isfinite(P).all(axis=1) & np.isfinite(Q).all(axis=1)
    out = np.zeros(len(P), bool)
    idx = np.flatnonzero(ok)
    if len(idx) < 8:
        return out
    P, Q = P[idx], Q[idx]
    k = min(neighbours, len(idx) - 1)
    nb = cKDTree(P).query(P, k + 1)[1][:, 1:]
    dp = np.linalg.norm(P[:, None] - P[nb], axis=-1)
    dq = np.linalg.norm(Q[:, None] - Q[nb], axis=-1)
    agree = (np.abs(dp - dq) < np.maximum(ABS_M, REL * dp)) & (dp >= MIN_DISTANCE_M) & (dq >= MIN_DISTANCE_M)
    out[idx] = agree.sum(axis=1) >= max(3, k // 3)
    return out


#: Rigid-motion hypotheses (each from 3 of the neighbours) tried per match by `locally_rigid`.
TRIALS = 24
#: A neighbour (and the match itself) agrees with a local rigid motion within this distance, metres.
RIGID_TOLERANCE_M = 0.005


def locally_rigid(P: np.ndarray, Q: np.ndarray, neighbours: int = NEIGHBOURS, trials: int = TRIALS,
                  tolerance_m: float = RIGID_TOLERANCE_M, seed: int = 0) -> np.ndarray:
    """(N,) bool: matches (P[i] -> Q[i], (N, 3) metres) that a rigid motion of their `neighbours`
    nearest matches (in P) carries within `tolerance_m`: the 3D analogue of
    `locally_consistent`'s local affine map (a small patch of a surface that bends without
    stretching moves almost rigidly). `trials` motions per match, each fitted (Kabsch) to 3
    neighbours; the best must carry at least a third of the neighbours (and 3) and the match itself."""
    ok = np.isfinite(P).all(axis=1) & np.isfinite(Q).all(axis=1)
    out = np.zeros(len(P), bool)
    idx = np.flatnonzero(ok)
    n = len(idx)
    if n < 8:
        return out
    P, Q = P[idx], Q[idx]
    rng = np.random.default_rng(seed)
    k = min(neighbours, n - 1)
    nb = cKDTree(P).query(P, k + 1)[1][:, 1:]  # (n, k)
    pick = np.argsort(rng.random((n, trials, k)), axis=2)[:, :, :3]
    trio = nb[np.arange(n)[:, None, None], pick]  # (n, S, 3)
    A, B = P[trio], Q[trio]  # (n, S, 3, 3): three points, xyz
    ca, cb = A.mean(axis=2, keepdims=True), B.mean(axis=2, keepdims=True)
    H = np.swapaxes(A - ca, -1, -2) @ (B - cb)  # (n, S, 3, 3)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)  # (n, S, 3, 3): b = R a + t
    area = np.linalg.norm(np.cross(A[:, :, 1] - A[:, :, 0], A[:, :, 2] - A[:, :, 0]), axis=-1)
    spans = area > (2 * tolerance_m) ** 2
    def carry(points, centre_a, centre_b):  # (n, [S,] m, 3) -> moved by each hypothesis
        return np.einsum("nsij,nsmj->nsmi", R, points - centre_a) + centre_b
    moved = carry(np.broadcast_to(P[nb][:, None], (n, trials, k, 3)), ca, cb)  # (n, S, k, 3)
    residual = np.linalg.norm(moved - Q[nb][:, None], axis=-1)
    support = (residual < tolerance_m).sum(axis=-1) * spans  # (n, S)
    best = np.argmax(support, axis=1)
    rows = np.arange(n)
    own = np.einsum("nij,nj->ni", R[rows, best], P - ca[rows, best, 0]) + cb[rows, best, 0]
    out[idx] = (np.linalg.norm(own - Q, axis=1) < tolerance_m) & (support[rows, best] >= max(3, k // 3))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cache", type=Path, required=True, help="pickle of the described frames")
    p.add_argument("--descriptors", default="geopatch", help="names in the cache, comma-separated")
    p.add_argument("--words", type=int, default=2560)
    p.add_argument("--depth", type=int, default=RERANK, help=f"results per query re-ranked (default {RERANK})")
    args = p.parse_args()
    db, queries, exclude, val, test, classes = cached_retrieval(args.cache)
    print("| descriptor | score | validation | test | all |\n|---|---|---|---|---|")
    for name in [d for d in args.descriptors.split(",") if d]:
        feats = db.features[name]
        nb = word_shortlist(feats, queries, exclude, args.words, args.depth)
        points = keypoint_points(db, feats)
        scores = np.zeros(nb.shape + (3,))  # (Q, depth, [affine, 3D distances, 3D rigid])
        for r, (q, row) in enumerate(tqdm(list(zip(queries, nb)), desc=f"{name}: pairs", unit="query")):
            for j, c in enumerate(row):
                m = match(feats[q], feats[c], mutual=True, ratio=RERANK_RATIO).matches0
                i0 = np.flatnonzero(m >= 0)
                if len(i0) < 8:
                    continue
                i1 = m[i0]
                scores[r, j, 0] = locally_consistent(feats[q].keypoints[i0], feats[c].keypoints[i1]).sum()
                scores[r, j, 1] = metric_consistent(points[q][i0], points[c][i1]).sum()
                scores[r, j, 2] = locally_rigid(points[q][i0], points[c][i1]).sum()
        runs = {"words only": None, "affine (the command)": scores[..., 0], "3D distances": scores[..., 1],
                "affine + 3D distances": scores[..., 0] + scores[..., 1], "3D rigid": scores[..., 2],
                "affine + 3D rigid": scores[..., 0] + scores[..., 2]}
        for label, s in runs.items():
            ranked = nb if s is None else np.take_along_axis(nb, np.argsort(-s, axis=1, kind="stable"), axis=1)
            acc = per_query_accuracy(ranked[:, :10], db.classes, classes[queries]).mean(axis=1)
            print(f"| {name} | {label} | {acc[val].mean():.3f} | {acc[test].mean():.3f} | {acc.mean():.3f} |")


if __name__ == "__main__":
    main()
