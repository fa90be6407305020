"""`geofeat bench` against a second, independent implementation of the published matching-score
protocol (docs/concepts.md, "Protocols", "detect") for OpenCV SIFT.

The independent scorer below uses OpenCV directly (SIFT detect + compute with nfeatures=2048 and
contrastThreshold=0.004 on the 8-bit gray image, brute-force L2 nearest neighbours, first index on
ties), scipy's KD-tree for the ground-truth partners, and nothing of geofeat's detection, matching or
scoring code; only the simulator's exact correspondences (the ground truth itself) are shared. The
sequences carry no geofeat.json (it is removed from a copy), like the public datasets.

    python benchmarks/protocol_check.py SEQUENCES... [--keypoints 2048]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

import geofeat
from geofeat.bench.report import read_results
from geofeat.bench.runner import BenchConfig, run_benchmark


def sift(image_bgr: np.ndarray, n: int):
    gray = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
    kps, desc = cv2.SIFT_create(nfeatures=n, contrastThreshold=0.004).detectAndCompute(gray, None)
    order = np.argsort([-k.response for k in kps], kind="stable")[:n]
    return np.array([kps[i].pt for i in order], float).reshape(-1, 2), desc[order]


def independent_ms(seq, n: int) -> float:
    """Mean MS over the pairs (reference, target) of one simulated sequence."""
    ref_img = cv2.imread(str(seq.folder / f"{seq.reference}-rgb.png"), cv2.IMREAD_COLOR)
    xr, dr = sift(ref_img, n)
    on_object = seq.correspondences(seq.reference, seq.reference, xr)[1]  # object mask
    xr, dr = xr[on_object], dr[on_object]
    scores = []
    for target in seq.targets:
        xt, dt = sift(cv2.imread(str(seq.folder / f"{target}-rgb.png"), cv2.IMREAD_COLOR), n)
        mapped, visible = seq.correspondences(target, seq.reference, xt)
        xt, dt, mapped = xt[visible], dt[visible], mapped[visible]
        d2 = ((dr[:, None, :].astype(np.float64) - dt[None, :, :]) ** 2).sum(-1)
        nn = d2.argmin(axis=1)  # one way, reference -> target, lowest index on ties
        dist, partner = cKDTree(xr).query(mapped)
        claimed, hits = set(), 0
        for t in range(len(xt)):  # first target claims a reference keypoint
            r = int(partner[t])
            if dist[t] < 3.0 and r not in claimed:
                claimed.add(r)
                hits += int(nn[r] == t)
        scores.append(hits / min(len(xr), len(xt)) if min(len(xr), len(xt)) else 0.0)
    return float(np.mean(scores))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequences", nargs="+")
    parser.add_argument("--keypoints", type=int, default=2048)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="geofeat-protocol-"))
    folders = []
    for folder in geofeat.io.find_sequences(args.sequences):
        copy = work / "data" / folder.name
        shutil.copytree(folder, copy)
        (copy / "geofeat.json").unlink(missing_ok=True)
        folders.append(copy)
    csv_path, failed = run_benchmark([work / "data"], work / "bench", BenchConfig(descriptors=("sift",),
                                     n_keypoints=args.keypoints), progress=False)
    rows = read_results(csv_path)
    print("| sequence | geofeat bench MS (SIFT) | independent MS | difference |")
    print("|---|---|---|---|")
    diffs = []
    for folder in folders:
        ours = np.mean([r["ms"] for r in rows if r["sequence"] == folder.name])
        theirs = independent_ms(geofeat.read_sequence(folder), args.keypoints)
        diffs.append(ours - theirs)
        print(f"| {folder.name} | {ours:.4f} | {theirs:.4f} | {ours - theirs:+.4f} |")
    print(f"\nlargest |difference|: {np.max(np.abs(diffs)):.4f} (goal <= 0.03)")
    shutil.rmtree(work)


if __name__ == "__main__":
    main()
