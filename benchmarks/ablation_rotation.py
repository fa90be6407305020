"""GeoPatch rotation ablation (paper appendix "Rotation Ablation"): no rotation invariance
(flatten) vs max-pool over the angle axis vs circular-shift augmentation (flatten + random column
rolls), same data and training budget, matching score on held-out rotate and deform sequences.

Run: .venv/bin/python benchmarks/ablation_rotation.py --train out/sim2/train --test out/difficulty/paper \
        [--cache PATCHES.npz --epochs 4 --steps 100 --batch-size 256 --channels 32 64 128]
(make the data first with benchmarks/make_sim_datasets.py and benchmarks/sim_difficulty.py). All
variants share the shipped recipe (paper widths, lr 0.1, hardest-in-batch mining, photometric
augmentation; --mining random for the paper's) and differ only in how they treat rotation.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from geofeat.bench.report import read_results, summary
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.descriptors.geopatch import GeoPatchConfig
from geofeat.train.dataset import PatchSet, build_patch_set
from geofeat.train.loop import TrainConfig, train

VARIANTS = {  # label: (max-pool over the angle axis, random column rolls in training)
    "no invariance (flatten)": (False, False),
    "max-pool over angle": (True, False),
    "shift augmentation": (False, True),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--train", type=Path, default=Path("out/sim/train"))
    parser.add_argument("--test", type=Path, default=Path("out/sim/test"))
    parser.add_argument("--out", type=Path, default=Path("out/ablation"))
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--keypoints", type=int, default=1024)
    parser.add_argument("--channels", type=int, nargs=3, default=(32, 64, 128))
    parser.add_argument("--lr", type=float, default=0.1)
    parser.add_argument("--mining", choices=("hardest", "random"), default="hardest",
                        help="hardest in batch (shipped) or the paper's random negative with anchor swap")
    parser.add_argument("--only", type=int, nargs="+", default=None,
                        help="run only these variants (0 flatten, 1 max-pool, 2 shift augmentation)")
    parser.add_argument("--cache", type=Path, default=None,
                        help="patch set of --train made before (a geofeat train .patches.npz)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cache = args.cache or args.out / "patches.npz"
    data = PatchSet.load(cache) if cache.is_file() else build_patch_set(args.train)
    if not cache.is_file():
        data.save(cache)
    results, minutes = {}, {}
    for i, (label, (angle_pool, shift)) in enumerate(VARIANTS.items()):
        if args.only is not None and i not in args.only:
            continue
        weights = args.out / f"variant{i}.pt"
        if not weights.is_file():
            config = TrainConfig(epochs=args.epochs, steps_per_epoch=args.steps, batch_size=args.batch_size,
                                 lr=args.lr, mining=args.mining, augment_shift=shift, augment_photometric=True,
                                 seed=0, net=GeoPatchConfig(channels=tuple(args.channels), angle_pool=angle_pool))
            start = time.perf_counter()
            train(data, weights, config, device="cpu")
            minutes[label] = (time.perf_counter() - start) / 60
        csv_path, _ = run_benchmark(args.test, args.out / f"bench{i}",
                                    BenchConfig(descriptors=(f"geopatch={weights}",), n_keypoints=args.keypoints))
        rows = read_results(csv_path)
        results[label] = {kind: summary([r for r in rows if kind in r["sequence"]]) for kind in ("rotate", "deform", "scale")}
    print(f"training: {args.epochs} x {args.steps} steps x {args.batch_size}, channels {tuple(args.channels)}, "
          f"lr {args.lr}, {args.mining} mining; "
          f"test: {args.test}")
    print("| variant | rotate MS | deform MS | scale MS | training time |\n|---|---|---|---|---|")
    for label, by_kind in results.items():
        cells = [f"{next(iter(s.values()))['ms']:.3f}" if s else "-" for s in by_kind.values()]
        took = f"{minutes[label]:.1f} min" if label in minutes else "(weights existed)"
        print(f"| {label} | " + " | ".join(cells) + f" | {took} |")


if __name__ == "__main__":
    main()
