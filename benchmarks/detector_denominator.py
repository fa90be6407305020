"""Where a detector's matching score comes from: hits, ground-truth pairs and the protocol's
denominator min(n_ref, n_tgt), per bench run.

The protocol drops target keypoints whose surface point is not visible in the reference (off the
object, occluded, out of view) before it counts n_tgt, so two detectors with the same hits can
differ in MS through the keypoints that the protocol does not charge them for.

    python benchmarks/detector_denominator.py NAME=BENCH_FOLDER ... [--descriptor geopatch]

Each BENCH_FOLDER is the --out folder of a `geofeat bench` run (its results.csv). Prints one
Markdown row per run: MS, repeatability, reference keypoints per frame, target keypoints kept per
pair, ground-truth pairs per pair, hits per pair, and ground-truth pairs per reference keypoint
(a repeatability that the target's dropped keypoints do not change).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from geofeat.bench.report import read_results

COLUMNS = ("ms", "repeatability", "n_ref", "n_tgt", "n_gt", "hits")


def run_means(folder: Path, descriptor: str | None) -> np.ndarray:
    """Mean over sequences of per-sequence means of `COLUMNS` (the bench's averaging rule)."""
    rows = read_results(folder / "results.csv")
    names = list(dict.fromkeys(r["descriptor"] for r in rows))
    name = descriptor if descriptor in names else names[0]
    per_seq: dict[str, list] = {}
    for r in rows:
        if r["descriptor"] == name:
            per_seq.setdefault(r["sequence"], []).append([float(r[k]) for k in COLUMNS])
    return np.mean([np.mean(v, axis=0) for v in per_seq.values()], axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="NAME=BENCH_FOLDER")
    parser.add_argument("--descriptor", default="geopatch",
                        help="descriptor to read (default geopatch; a run without it uses its first)")
    args = parser.parse_args()
    print("| run | MS | repeatability | ref. keypoints / frame | target keypoints kept / pair "
          "| ground-truth pairs / pair | hits / pair | pairs / ref. keypoint |")
    print("|---|---|---|---|---|---|---|---|")
    for spec in args.runs:
        name, _, folder = spec.partition("=")
        ms, rep, n_ref, n_tgt, n_gt, hits = run_means(Path(folder), args.descriptor)
        print(f"| {name} | {ms:.3f} | {rep:.3f} | {n_ref:.0f} | {n_tgt:.0f} | {n_gt:.0f} | {hits:.0f} "
              f"| {n_gt / max(n_ref, 1):.3f} |")


if __name__ == "__main__":
    main()
