"""Millimetre depth: the matching score of each depth profile on simulated sequences rewritten in
the public layout's unit.

`geofeat simulate` writes depth in 0.1 mm steps; the public dataset layout (and, most likely, other
simulators' renders) stores millimetres. This script copies each sequence folder given, with its
depth PNGs rounded to millimetres and without its geofeat.json (so, as for outside data, the unit
is the layout's default and the profile "auto"), then runs the benchmark on the copies with every
fixed profile and with "auto", and on the originals with "auto" for reference.

    PYTHONPATH=src python benchmarks/depth_units.py out/difficulty/paper out/difficulty/hard \
        [--detector geokey] [--descriptors geopatch,geobit] [--keypoints 2048] [--work DIR] [--step-mm 1]

`--step-mm` rounds the copies to another step instead (their geofeat.json then gives only the
depth scale), to see where between the simulator's 0.1 mm and millimetres each profile wins.

Prints one row per set, profile and descriptor: the mean over sequences of the per-sequence mean MS.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from geofeat.bench.report import read_results, summary
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.constants import DEPTH_SCALE_M
from geofeat.depth import PROFILES, depth_noise
from geofeat.io import DEPTH_SUFFIX, find_sequences, read_sequence


def requantised(sequence: Path, out: Path, step_m: float = DEPTH_SCALE_M) -> Path:
    """Copy one sequence folder to `out`, depth PNGs rounded to steps of `step_m` metres. In
    millimetres (the layout's default unit) the copy has no geofeat.json, as outside data; another
    step gets a geofeat.json that gives only its `depth_scale`."""
    scale = read_sequence(sequence).depth_scale  # metres per unit of the original PNGs
    out.mkdir(parents=True, exist_ok=True)
    for f in sequence.iterdir():
        if f.name == "geofeat.json" or not f.is_file():
            continue
        if f.name.endswith(DEPTH_SUFFIX):
            units = cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float64)
            cv2.imwrite(str(out / f.name), np.rint(units * scale / step_m).astype(np.uint16))
        else:
            shutil.copy2(f, out / f.name)
    if step_m != DEPTH_SCALE_M:
        (out / "geofeat.json").write_text(json.dumps({"depth_scale": step_m}))
    return out


def mean_ms(folders: list[Path], out: Path, profile: str, args) -> dict[str, float]:
    """{descriptor: MS} of the benchmark on `folders` with one depth profile."""
    config = BenchConfig(descriptors=tuple(args.descriptors.split(",")), n_keypoints=args.keypoints,
                         detector=args.detector, depth_profile=profile)
    csv_path, _ = run_benchmark(folders, out, config, progress=False, overwrite=True)
    return {name: s["ms"] for name, s in summary(read_results(csv_path)).items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sets", nargs="+", help="folders of simulated sequences (e.g. out/difficulty/paper)")
    ap.add_argument("--detector", default="geokey")
    ap.add_argument("--descriptors", default="geopatch,geobit")
    ap.add_argument("--keypoints", type=int, default=2048)
    ap.add_argument("--work", help="folder for the millimetre copies and the results (default: a temporary one)")
    ap.add_argument("--step-mm", type=float, default=1.0,
                    help="depth step of the copies, millimetres (default 1: the public layout's unit)")
    args = ap.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="depth_units_"))
    print(f"detector {args.detector}, {args.keypoints} keypoints; copies and results in {work}")
    print("| set | depth PNG | profile | " + " | ".join(args.descriptors.split(",")) + " |")
    print("|---|---|---|" + "---|" * len(args.descriptors.split(",")))
    for set_dir in map(Path, args.sets):
        originals = find_sequences([set_dir])
        unit = f"{args.step_mm:g} mm"
        copies = [requantised(seq, work / unit.replace(" ", "") / set_dir.name / seq.name, args.step_mm / 1000)
                  for seq in originals]
        steps = [depth_noise(f.depth, f.K).step_per_footprint
                 for f in (seq.frame(seq.reference) for seq in map(read_sequence, copies))]
        print(f"| {set_dir.name} | {unit}: steps of {min(steps):.2f}-{max(steps):.2f} pixel footprints "
              "(reference frames) | |" + " |" * len(args.descriptors.split(",")), flush=True)
        runs = [("original", originals, "auto")] + [(unit, copies, p) for p in (*PROFILES, "auto")]
        for label, folders, profile in runs:
            ms = mean_ms(folders, work / "bench" / set_dir.name / f"{label.replace(' ', '')}-{profile}", profile, args)
            print(f"| {set_dir.name} | {label} | {profile} | " + " | ".join(f"{ms[d]:.3f}" for d in ms) + " |", flush=True)


if __name__ == "__main__":
    main()
