"""Depth profiles: the noise statistic per kind of data, and the matching score of GeoPatch and
GeoBit with each fixed profile and with `auto`.

Data (made here, in a temporary folder unless --data is given):
- the shipped real Kinect v1 frame, and a two-target sequence of it seen by the camera rolled by
  30 and 60 degrees (ground truth: a thin-plate spline on the 51 annotated landmarks);
- `--sequences` clean simulated deformation sequences (the simulator's 0.1 mm depth PNGs, no sensor noise);
- as many sequences with the same seeds and the simulator's Kinect noise model (`geofeat simulate
  --kinect-noise`): the same scenes with noise added (the noise has a generator of its own; before
  that fix, these were other scenes of the same kind from the second frame on, as in BENCHMARKS.md).

Prints the statistic `geofeat.depth_noise(...).slope_noise` (depth noise in units of the pixel
footprint; `auto` picks "kinect" above `geofeat.depth.SLOPE_NOISE_THRESHOLD`) and, per kind of data,
the mean matching score of each descriptor with the profiles kinect, quantised, clean and auto, and
auto's share of the best fixed profile (the goal is at least 0.97).

    python benchmarks/depth_profiles.py [--sequences 4] [--frames 5] [--keypoints 2048]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import geofeat
from geofeat.bench.report import read_results, summary
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.depth import SLOPE_NOISE_THRESHOLD, depth_noise
from geofeat.frame import roll_camera
from geofeat.io import demo_data_dir, read_landmarks, write_frame, write_intrinsics, write_landmarks
from geofeat.sim import simulate_sequence


def kinect_sequence(root: Path) -> Path:
    folder = root / "kinect" / "cloud_1-roll"
    folder.mkdir(parents=True)
    frame = geofeat.read_demo_frame()
    ids, xy, visible = read_landmarks(demo_data_dir() / "cloud_1.csv")
    write_intrinsics(folder / "intrinsics.xml", frame.K)
    write_frame(folder, "cloud_ref", frame.color, frame.depth)
    write_landmarks(folder / "cloud_ref.csv", ids, xy, visible)
    for angle in (30, 60):
        rolled, A = roll_camera(frame, angle)
        write_frame(folder, f"cloud_roll{angle}", rolled.color, rolled.depth)
        write_landmarks(folder / f"cloud_roll{angle}.csv", ids, xy @ A[:, :2].T + A[:, 2], visible)
    return folder.parent


def simulated(root: Path, n: int, frames: int, kinect_noise: bool) -> Path:
    kind = "sim-kinect-noise" if kinect_noise else "sim-clean"
    for seed in range(n):
        simulate_sequence(root / kind / f"s{seed}-deform", scenario="deform", n_frames=frames, seed=100 + seed,
                          kinect_noise=kinect_noise, progress=False)
    return root / kind


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequences", type=int, default=4)
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--keypoints", type=int, default=2048)
    parser.add_argument("--descriptors", default="geopatch,geobit")
    parser.add_argument("--data", default=None, help="keep the generated data here (default: a temporary folder); "
                                                     "data already there is reused")
    parser.add_argument("--noise-only", action="store_true", help="print the noise statistic only")
    args = parser.parse_args()
    root = Path(args.data or tempfile.mkdtemp(prefix="geofeat-profiles-"))

    def reuse(folder: Path, make):
        return folder if folder.is_dir() else make()

    kinds = {"real Kinect (rolled pair)": reuse(root / "kinect", lambda: kinect_sequence(root)),
             "simulated, clean depth": reuse(root / "sim-clean", lambda: simulated(root, args.sequences, args.frames, False)),
             "simulated, Kinect noise": reuse(root / "sim-kinect-noise",
                                              lambda: simulated(root, args.sequences, args.frames, True))}

    print(f"slope noise (sigma_z / pixel footprint); auto picks kinect above {SLOPE_NOISE_THRESHOLD}\n")
    print("| data | frames | slope noise: min / median / max | relative noise (median) | auto picks |")
    print("|---|---|---|---|---|")
    for kind, folder in kinds.items():
        stats, picks = [], []
        for seq_folder in geofeat.io.find_sequences([folder]):
            seq = geofeat.read_sequence(seq_folder)
            for name in seq.names:
                frame = seq.frame(name)
                stats.append(depth_noise(frame.depth, frame.K))
                picks.append(geofeat.depth_profile(frame))
        slope = np.array([s.slope_noise for s in stats])
        rel = np.median([s.relative_noise for s in stats])
        counts = ", ".join(f"{p} {picks.count(p)}" for p in sorted(set(picks)))
        print(f"| {kind} | {len(stats)} | {slope.min():.3f} / {np.median(slope):.3f} / {slope.max():.3f} | "
              f"{rel:.2e} | {counts} |")

    if args.noise_only:
        return
    names = tuple(args.descriptors.split(","))
    print("\n| data | descriptor | MS kinect | MS quantised | MS clean | MS auto | auto / best fixed |")
    print("|---|---|---|---|---|---|---|")
    for kind, folder in kinds.items():
        scores = {}
        for profile in ("kinect", "quantised", "clean", "auto"):
            out = root / "bench" / kind.replace(" ", "_").replace(",", "") / profile
            config = BenchConfig(descriptors=names, n_keypoints=args.keypoints, depth_profile=profile)
            csv_path, _ = run_benchmark([folder], out, config, progress=False, overwrite=True)
            scores[profile] = summary(read_results(csv_path))
        for name in names:
            ms = {p: scores[p][name]["ms"] for p in scores}
            best = max(ms["kinect"], ms["quantised"], ms["clean"])
            print(f"| {kind} | {name} | {ms['kinect']:.3f} | {ms['quantised']:.3f} | {ms['clean']:.3f} | "
                  f"{ms['auto']:.3f} | {ms['auto'] / best if best else float('nan'):.3f} |")
    print(f"\ndata in {root}")


if __name__ == "__main__":
    main()
