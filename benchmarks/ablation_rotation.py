"""GeoPatch rotation ablation (paper appendix "Rotation Ablation"): no rotation invariance
(flatten) vs max-pool over the angle axis vs circular-shift augmentation (flatten + random column
rolls), same data and training budget, matching score on held-out rotate and deform sequences.

Run: .venv/bin/python benchmarks/ablation_rotation.py --train out/sim/train --test out/sim/test \
        [--epochs 3 --steps 100 --batch-size 256]
(make the data first with benchmarks/make_sim_datasets.py)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from geofeat.bench.report import read_results, summary
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.descriptors.geopatch import GeoPatchConfig
from geofeat.train.dataset import PatchSet, build_patch_set
from geofeat.train.loop import TrainConfig, train

VARIANTS = {
    "no invariance (flatten)": dict(net=GeoPatchConfig(angle_pool=False), augment_shift=False),
    "max-pool over angle": dict(net=GeoPatchConfig(angle_pool=True), augment_shift=False),
    "shift augmentation": dict(net=GeoPatchConfig(angle_pool=False), augment_shift=True),
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
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cache = args.out / "patches.npz"
    data = PatchSet.load(cache) if cache.is_file() else build_patch_set(args.train)
    data.save(cache)
    results = {}
    for i, (label, variant) in enumerate(VARIANTS.items()):
        weights = args.out / f"variant{i}.pt"
        if not weights.is_file():
            config = TrainConfig(epochs=args.epochs, steps_per_epoch=args.steps, batch_size=args.batch_size,
                                 mining="hardest", seed=0, **variant)
            train(data, weights, config, device="cpu")
        csv_path, _ = run_benchmark(args.test, args.out / f"bench{i}",
                                    BenchConfig(descriptors=(f"geopatch={weights}",), n_keypoints=args.keypoints))
        rows = read_results(csv_path)
        results[label] = {kind: summary([r for r in rows if kind in r["sequence"]]) for kind in ("rotate", "deform", "scale")}
    print("| variant | rotate MS | deform MS | scale MS |\n|---|---|---|---|")
    for label, by_kind in results.items():
        cells = [f"{next(iter(s.values()))['ms']:.3f}" if s else "-" for s in by_kind.values()]
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
