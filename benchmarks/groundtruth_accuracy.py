"""Accuracy and speed of `geofeat groundtruth` against the simulator's exact correspondences.

Simulated `deform` sequences (640x480) keep only 25 landmark rows per csv (drawn with a seed, as a
person would annotate a few points); ground truth is generated with and without photometric
refinement and its target -> reference mapping is compared with the exact one at every 4th pixel of
the cloth visible in both frames, inside and outside the convex hull of the landmarks. Then
`geofeat bench` (SIFT, ORB) is run with the exact ground truth, the refined files and the
landmark-only files. A control-point spacing sweep on the first sequence chose the default.
Seconds per frame: wall time and CPU time of the process (all threads) on this (shared) machine;
the ratio refined / landmark-only is measured in the same process.

Run: .venv/bin/python benchmarks/groundtruth_accuracy.py [--seeds 1,2,3] [--frames 8] [--sweep 8,12,20]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from geofeat.bench.report import read_results
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.groundtruth import DEFAULT_SPACING_PX, GroundTruthConfig, generate_ground_truth
from geofeat.groundtruth.validate import keep_landmarks, mapping_errors
from geofeat.io import read_sequence
from geofeat.sim import simulate_sequence


def _stats(e: np.ndarray) -> str:
    return f"{np.median(e):6.2f} | {np.percentile(e, 90):6.2f}" if len(e) else "     - |      -"


def _run(seqs, out: Path, refine: bool, spacing: float, targets=None):
    """Generate ground truth for every sequence; returns pooled inside/outside errors and wall and CPU
    (this process, all threads) seconds per frame."""
    inside, outside, seconds, cpu, frames = [], [], 0.0, 0.0, 0
    for seq in seqs:
        folder = out / seq.name
        t, c = time.perf_counter(), time.process_time()
        reports = generate_ground_truth(seq, folder, GroundTruthConfig(refine=refine, spacing=spacing), progress=False)
        seconds += time.perf_counter() - t
        cpu += time.process_time() - c
        frames += len(reports)
        for r in reports:
            if r.status != "ok":
                print(f"  {seq.name}/{r.frame}: FAILED {r.reason}")
                continue
            e = mapping_errors(seq, folder, r.frame)
            inside.append(e.inside)
            outside.append(e.outside)
    n = max(frames, 1)
    return np.concatenate(inside), np.concatenate(outside), (seconds / n, cpu / n)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/groundtruth_accuracy"))
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--landmarks", type=int, default=25)
    ap.add_argument("--sweep", default="8,20", help="extra spacings tried on the first sequence (default 8,20)")
    ap.add_argument("--descriptors", default="sift,orb")
    ap.add_argument("--sweep-only", action="store_true", help="only the spacing sweep, with exactly the --sweep spacings")
    args = ap.parse_args()
    seqs = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        full = args.out / "sim" / f"deform-s{seed}"
        if not full.is_dir():
            simulate_sequence(full, "deform", n_frames=args.frames, seed=seed, progress=False)
        seqs.append(read_sequence(keep_landmarks(full, args.out / "data" / f"deform-s{seed}", args.landmarks, seed=seed)))
    n_targets = sum(len(s.targets) for s in seqs)
    print(f"{len(seqs)} simulated deform sequences, {n_targets} target frames, {args.landmarks} landmarks kept per csv\n")

    if not args.sweep_only:
        _tables(args, seqs)
    sweep = [float(s) for s in args.sweep.split(",") if s]
    if sweep:
        print(f"\nControl-point spacing on {seqs[0].name} ({len(seqs[0].targets)} frames):\n")
        print("| spacing px | inside median | inside p90 | outside median | outside p90 | wall s/frame | CPU s/frame |")
        print("|---|---|---|---|---|---|---|")
        for sp in sorted(set(sweep + ([] if args.sweep_only else [DEFAULT_SPACING_PX]))):
            i, o, s = _run(seqs[:1], args.out / f"gt-spacing{sp:g}", True, sp)
            print(f"| {sp:g} | {_stats(i)} | {_stats(o)} | {s[0]:.2f} | {s[1]:.2f} |", flush=True)


def _tables(args, seqs) -> None:
    """Errors of the landmark-only and the refined ground truth, and the bench with each."""
    results = {}
    for label, refine in (("landmark-only TPS (--no-refine)", False), (f"refined, spacing {DEFAULT_SPACING_PX:g} px", True)):
        results[refine] = _run(seqs, args.out / ("gt-refined" if refine else "gt-landmarks"), refine, DEFAULT_SPACING_PX)
    print("Target -> reference error (px) at cloth pixels visible in both frames (every 4th pixel):\n")
    print("| ground truth | inside hull median | inside p90 | outside hull median | outside p90 | wall s/frame | CPU s/frame |")
    print("|---|---|---|---|---|---|---|")
    for refine, label in ((False, "landmark-only TPS (`--no-refine`)"), (True, f"refined (spacing {DEFAULT_SPACING_PX:g} px)")):
        i, o, s = results[refine]
        print(f"| {label} | {_stats(i)} | {_stats(o)} | {s[0]:.2f} | {s[1]:.2f} |")
    i0, o0, s0 = results[False]
    i1, o1, s1 = results[True]
    print(f"\ninside the hull: p90 {100 * (1 - np.percentile(i1, 90) / np.percentile(i0, 90)):.0f} % lower; "
          f"points: {len(i0)} inside, {len(o0)} outside; refinement costs {s1[1] / s0[1]:.0f}x the landmark spline's CPU time")

    print("\nMatching score with each ground truth (`geofeat bench`, protocol detect):\n")
    config = BenchConfig(descriptors=tuple(args.descriptors.split(",")))
    ms = {}
    for label, tps in (("exact (simulator)", None), ("refined files", args.out / "gt-refined"),
                       ("landmark-only files", args.out / "gt-landmarks")):
        config.tps_dir = None if tps is None else str(tps)
        csv_path, failed = run_benchmark(args.out / "data", args.out / f"bench-{label.split()[0]}", config, progress=False)
        rows = read_results(csv_path)
        ms[label] = {d: np.mean([np.mean([float(r["ms"]) for r in rows if r["descriptor"] == d and r["sequence"] == s.name])
                                 for s in seqs]) for d in config.descriptors}
    print("| ground truth | " + " | ".join(config.descriptors) + " |")
    print("|---|" + "---|" * len(config.descriptors))
    for label, row in ms.items():
        diff = "" if label.startswith("exact") else " (" + ", ".join(
            f"{row[d] - ms['exact (simulator)'][d]:+.3f}" for d in config.descriptors) + ")"
        print(f"| {label}{diff} | " + " | ".join(f"{row[d]:.3f}" for d in config.descriptors) + " |")


if __name__ == "__main__":
    main()
