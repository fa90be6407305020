"""Wall time of `geofeat bench` (GeoBit + ORB + SIFT) on 10-frame 640x480 simulated sequences with
1 and 2 worker processes, and where the time goes (detection, description, matching).
Run: .venv/bin/python benchmarks/bench_runner.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import geofeat
from geofeat.bench.report import read_results
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.keypoints import detect
from geofeat.sim import simulate_sequence


def main() -> None:
    root = Path("out/bench_speed")
    for i in range(2):
        folder = root / "data" / f"seq{i}-deform"
        if not folder.is_dir():
            simulate_sequence(folder, scenario="deform", n_frames=10, seed=500 + i, progress=False)
    config = BenchConfig(descriptors=("geobit", "orb", "sift"))
    for data, label in ((root / "data" / "seq0-deform", "1 sequence"), (root / "data", "2 sequences")):
        for workers in (1, 2):
            t = time.perf_counter()
            csv_path, failed = run_benchmark(data, root / f"out-{workers}", config, workers=workers, progress=False)
            wall = time.perf_counter() - t
            print(f"{label}, {workers} worker(s): {wall:6.2f} s wall")
    rows = read_results(root / "out-1" / "results.csv")
    seq = geofeat.read_sequence(root / "data" / "seq0-deform")
    t = time.perf_counter()
    for name in seq.names:
        detect(seq.frame(name), detector="sift")
    t_detect_io = time.perf_counter() - t
    rows0 = [r for r in rows if r["sequence"] == "seq0-deform"]
    print("one sequence (10 frames, 9 pairs), single worker, seconds:")
    print(f"  read + SIFT detection of 10 frames   {t_detect_io:6.2f}")
    for name in config.descriptors:
        ext = sum(r["seconds_extract"] for r in rows0 if r["descriptor"] == name)
        mat = sum(r["seconds_match"] for r in rows0 if r["descriptor"] == name)
        print(f"  {name:6s} description {ext:6.2f}   matching {mat:6.2f}")
    print(f"  (description of the reference is counted in every pair's seconds_extract; mean n_ref "
          f"{np.mean([int(r['n_ref']) for r in rows0]):.0f})")


if __name__ == "__main__":
    main()
