"""The paper's two applications on simulated sequences with exact ground truth.

Simulates (once, cached under --data) deformation sequences of the three scenarios (deform, rotate,
scale), then prints:
- tracking (`geofeat track`): per descriptor the inlier rate, matching score of the kept matches,
  SSIM / NCC inside the ROI, and the median error of the tracked 10 x 10 grid against the
  simulator's exact ground truth (pixels), averaged over sequences; per scenario too;
- retrieval (`geofeat retrieval`): Acc@K of every descriptor; sequences simulated with the same
  texture are one object class.

    PYTHONPATH=src python benchmarks/applications.py --data /tmp/apps_data --out /tmp/apps_out \
        --texture-dir /work/shared/data/textures [--docs docs]

With --docs, copies the Acc@K plot and one GeoPatch tracking frame (PNG) there for the README.
Timings are wall-clock on whatever machine runs it (inflated when it is shared).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import time
from pathlib import Path

import numpy as np

from geofeat.io import find_sequences
from geofeat.apps.retrieval import run_retrieval
from geofeat.sim import simulate_sequence
from geofeat.apps.tracking import tracking_table, write_tracking


def simulate(data: Path, scenarios, seeds, frames: int, texture_dir) -> list[Path]:
    folders = []
    for scenario in scenarios:
        for seed in seeds:
            folder = data / f"{scenario}_s{seed}"
            if not (folder / "groundtruth.json").is_file():
                simulate_sequence(folder, scenario=scenario, n_frames=frames, seed=seed, texture_dir=texture_dir,
                                  progress=False, overwrite=True)
            folders.append(folder)
    return folders


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=Path("/tmp/geofeat_apps_data"), help="simulated sequences (cached)")
    p.add_argument("--out", type=Path, default=Path("/tmp/geofeat_apps_out"))
    p.add_argument("--scenarios", default="deform,rotate,scale")
    p.add_argument("--seeds", default="1,2", help="one sequence per scenario and seed")
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--texture-dir", default=None, help="textures for the simulator (default: packaged photographs)")
    p.add_argument("--descriptors", default="geopatch,geobit,sift,orb")
    p.add_argument("--keypoints", type=int, default=2048)
    p.add_argument("--sequences", nargs="*", type=Path, default=None,
                   help="existing sequences to track (instead of simulating --scenarios x --seeds)")
    p.add_argument("--retrieval-sequences", nargs="*", type=Path, default=None,
                   help="sequences for retrieval (default: the tracked ones)")
    p.add_argument("--classes", default=None,
                   help="CSV sequence,class for retrieval (default: by simulator texture when known, else folder name)")
    p.add_argument("--threshold", type=float, default=3.0, help="RANSAC inlier threshold, pixels (default 3)")
    p.add_argument("--skip-retrieval", action="store_true")
    p.add_argument("--skip-tracking", action="store_true")
    p.add_argument("--docs", type=Path, default=None, help="copy acc_at_k.png and a tracking frame PNG here")
    args = p.parse_args()

    names = tuple(args.descriptors.split(","))
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.sequences:
        folders = [Path(f) for f in find_sequences(args.sequences)]
    else:
        folders = simulate(args.data, args.scenarios.split(","), seeds, args.frames, args.texture_dir)
    print(f"tracking sequences: {', '.join(f.name for f in folders)}")
    if not args.skip_tracking:
        track(folders, names, args)
    if not args.skip_retrieval:
        retrieval(find_sequences(args.retrieval_sequences) if args.retrieval_sequences else folders, names, args)
    if args.docs is not None:
        docs(folders, names, args)


def track(folders, names, args) -> None:
    t = time.perf_counter()
    csv_path, table = write_tracking(folders, args.out / "track", names, n_keypoints=args.keypoints,
                                      threshold_px=args.threshold)
    t_track = time.perf_counter() - t
    rows = list(csv.DictReader(open(csv_path)))
    print(f"\n## Tracking (all sequences, RANSAC threshold {args.threshold:g} px)\n")
    print(table)
    for scenario in args.scenarios.split(","):
        sel = [r for r in rows if r["sequence"].startswith(scenario)]
        if not sel:
            continue
        print(f"\n### {scenario}\n")
        print(tracking_table(sel))
    print("grid error per descriptor, pixels (all target frames pooled: median / 90th percentile / max):")
    for name in names:
        e = np.array([float(r["grid_error_px"]) for r in rows if r["descriptor"] == name])
        e = np.where(np.isfinite(e), e, np.inf)  # a failed frame counts as lost
        print(f"  {name:10s} {np.median(e):7.2f} / {np.percentile(e, 90):7.2f} / {e.max():7.2f}")
    print(f"tracking wall time: {t_track:.0f} s for {len(rows) // len(names)} target frames x {len(names)} descriptors")


def retrieval(folders, names, args) -> None:
    print(f"retrieval sequences: {', '.join(Path(f).name for f in folders)}")
    t = time.perf_counter()
    classes = args.classes
    if classes is None:  # sequences simulated with the same texture show the same object
        classes = args.out / "classes.csv"
        args.out.mkdir(parents=True, exist_ok=True)
        lines = ["sequence,class"]
        for f in folders:
            meta = Path(f) / "groundtruth.json"
            texture = json.loads(meta.read_text()).get("texture") if meta.is_file() else None
            lines.append(f"{Path(f).name},{texture or Path(f).name}")
        classes.write_text("\n".join(lines) + "\n")
    acc, db = run_retrieval(folders, args.out / "retrieval", names, n_keypoints=args.keypoints,
                            classes_file=str(classes))
    t_ret = time.perf_counter() - t
    print("\n## Retrieval\n")
    print((args.out / "retrieval" / "retrieval.md").read_text())
    print("Acc@K, K = 1..10:")
    for name, r in acc.items():
        print(f"  {name:10s} " + " ".join(f"{v:.2f}" for v in r.accuracy))
    print(f"retrieval wall time: {t_ret:.0f} s")


def docs(folders, names, args) -> None:
    """Copy the Acc@K plot; draw the reference and last frame of the first rotate sequence with the
    grid tracked by the first descriptor, side by side at full resolution."""
    from geofeat.io import read_sequence
    from geofeat.apps.tracking import TrackResult, grid_frames

    args.docs.mkdir(parents=True, exist_ok=True)
    if (args.out / "retrieval" / "acc_at_k.png").is_file():
        shutil.copy(args.out / "retrieval" / "acc_at_k.png", args.docs / "retrieval_acc_at_k.png")
    if not (args.out / "track").is_dir():
        return
    hard = [f for f in folders if f.name.startswith("rotate")] or folders
    with np.load(args.out / "track" / hard[0].name / names[0] / "grid.npz") as g:
        result = TrackResult(hard[0].name, names[0], tuple(g["roi"]), [str(f) for f in g["frames"]],
                             g["reference_points"], g["points"])
    result.frames, result.points = [result.frames[0], result.frames[-1]], result.points[[0, -1]]
    pictures = grid_frames(read_sequence(hard[0]), result, scale=1.0)
    from PIL import Image  # a 128-colour palette keeps the README picture small

    Image.fromarray(np.concatenate(pictures, axis=1)).quantize(128).save(args.docs / "tracking_frame.png", optimize=True)
    print(f"wrote {args.docs / 'tracking_frame.png'} ({hard[0].name}, {names[0]}: reference and last frame)")

if __name__ == "__main__":
    main()
