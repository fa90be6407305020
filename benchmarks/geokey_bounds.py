"""Where GeoKey loses repeatability: the protocol's repeatability per scenario, beside two bounds
that no detector with the same keypoint counts, or the same localisation error, could pass.

For each (reference, target) pair of each sequence, at each keypoint count n:
- `repeatability`: the protocol's (`geofeat.train.detector.validation_scores`: ground-truth pairs
  < 3 px over min(reference keypoints, target keypoints visible in the reference)).
- `count bound`: min(reference keypoints visible in the target, target keypoints kept) over the same
  denominator. A reference keypoint pairs with one target keypoint at most, so no detector that
  returns these counts, and puts its reference keypoints where GeoKey does, can do better.
- `localisation bound, e px`: the share of the reference keypoints visible in the target that
  still lie within 3 px of themselves after a round trip: mapped into the target by the ground
  truth, moved there by Gaussian noise of e px per axis (a detector that finds the same surface
  point up to e target pixels), mapped back. A target seen from farther away, or obliquely,
  magnifies its pixel errors in the reference.

    PYTHONPATH=src python benchmarks/geokey_bounds.py out/det2/val/*hard*
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from common import simulated_as
from geofeat.detectors.geokey import detect_geokey
from geofeat.io import read_sequence
from geofeat.scoring import GT_THRESHOLD_PX, ground_truth_pairs

ERRORS_PX = (0.5, 1.0)


def pair_figures(seq, ref_xy: np.ndarray, target: str, n: int, rng: np.random.Generator) -> list[float]:
    """[repeatability, count bound, localisation bound per ERRORS_PX] of one pair."""
    tgt = detect_geokey(seq.frame(target), n).xy
    mapped, visible = seq.correspondences(target, seq.reference, tgt)
    kept = int(visible.sum())
    denom = min(len(ref_xy), kept)
    pairs = len(ground_truth_pairs(ref_xy, mapped[visible]))
    in_target, seen = seq.correspondences(seq.reference, target, ref_xy)
    row = [pairs / denom if denom else 0.0, min(int(seen.sum()), kept) / denom if denom else 0.0]
    for error in ERRORS_PX:
        moved = in_target[seen] + rng.normal(0.0, error, (int(seen.sum()), 2))
        back, ok = seq.correspondences(target, seq.reference, moved)
        close = ok & (np.linalg.norm(np.where(ok[:, None], back, 0.0) - ref_xy[seen], axis=1) < GT_THRESHOLD_PX)
        row.append(float(close.mean()) if len(close) else 0.0)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequences", nargs="+", type=Path, help="simulated sequence folders with ground truth")
    ap.add_argument("--keypoints", default="1024,2048")
    a = ap.parse_args()
    counts = [int(n) for n in a.keypoints.split(",")]
    rng = np.random.default_rng(0)
    per_seq: dict = defaultdict(list)  # (scenario, n) -> per-sequence means
    for folder in a.sequences:
        seq = read_sequence(folder)
        scenario = simulated_as(folder) or folder.name
        ref_frame = seq.frame(seq.reference)
        for n in counts:
            ref = detect_geokey(ref_frame, n).xy
            ref = ref[seq.correspondences(seq.reference, seq.reference, ref)[1]]
            rows = [pair_figures(seq, ref, target, n, rng) for target in seq.targets]
            per_seq[(scenario, n)].append(np.mean(rows, axis=0))
            per_seq[("all", n)].append(np.mean(rows, axis=0))
    print(f"{len(a.sequences)} sequences; load average {os.getloadavg()[0]:.2f}")
    errors = " | ".join(f"localisation bound, {e:g} px" for e in ERRORS_PX)
    print(f"| scenario | keypoints | sequences | repeatability | count bound | {errors} |")
    print("|---|---|---|---|---|" + "---|" * len(ERRORS_PX))
    for (scenario, n), rows in sorted(per_seq.items(), key=lambda item: (item[0][0] == "all", item[0])):
        cells = " | ".join(f"{v:.3f}" for v in np.mean(rows, axis=0))
        print(f"| {scenario} | {n} | {len(rows)} | {cells} |")


if __name__ == "__main__":
    main()
