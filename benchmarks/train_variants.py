"""GeoPatch training variants on one budget: negative mining (the paper's random negative with anchor
swap, or the hardest negative in the batch) and training-set size (a random fraction of the surface
points, or more patch sets). Every variant uses the shipped network shape and recipe otherwise
(paper widths 32/64/128, SGD lr 0.1 with cosine decay, photometric augmentation) and is scored on
the held-out validation sequences with `geofeat train`'s validation matching score.

    PYTHONPATH=src .venv/bin/python benchmarks/train_variants.py --data A.patches.npz [B.patches.npz ...] \\
        --val out/sim2/val --out out/variants [--epochs 4 --steps 100 --batch-size 256] \\
        [--variants hardest,random,hardest@0.5,hardest@0.25]

A variant is MINING[@FRACTION]; FRACTION (default 1) keeps that share of the surface points (all
their patches). Patch sets come from `geofeat train` (its OUT.patches.npz cache) or
`geofeat.train.build_patch_set(...).save(...)`. Prints a markdown table: patches, surface points,
training minutes, validation MS.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from geofeat.descriptors.geopatch import GeoPatchConfig, load_network
from geofeat.train.dataset import PatchSet, validation_pairs
from geofeat.train.loop import TrainConfig, train, validation_score


def load_patch_sets(paths: list[Path]) -> PatchSet:
    """Concatenate patch sets, keeping surface-point ids distinct across sets."""
    patches, ids, offset = [], [], 0
    for path in paths:
        part = PatchSet.load(path)
        patches.append(part.patches)
        ids.append(part.ids + offset)
        offset += int(part.ids.max()) + 1 if len(part) else 0
    return PatchSet(np.concatenate(patches), np.concatenate(ids))


def keep_fraction(data: PatchSet, fraction: float, seed: int = 0) -> PatchSet:
    """All patches of a random `fraction` of the surface points."""
    if fraction >= 1:
        return data
    points = np.unique(data.ids)
    chosen = np.random.default_rng(seed).choice(points, size=max(2, round(fraction * len(points))), replace=False)
    mask = np.isin(data.ids, chosen)
    return PatchSet(data.patches[mask], data.ids[mask])


def parse_variant(text: str) -> tuple[str, float]:
    mining, _, fraction = text.partition("@")
    if mining not in ("random", "hardest"):
        raise SystemExit(f"--variants: mining must be random or hardest, got {mining!r}")
    value = float(fraction) if fraction else 1.0
    if not 0 < value <= 1:
        raise SystemExit(f"--variants: fraction must be in (0, 1], got {fraction}")
    return mining, value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, nargs="+", required=True, help="patch sets (.npz)")
    ap.add_argument("--val", type=Path, required=True, help="folder of validation sequences")
    ap.add_argument("--out", type=Path, default=Path("out/variants"))
    ap.add_argument("--variants", default="hardest,random,hardest@0.5,hardest@0.25")
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--channels", type=int, nargs=3, default=(32, 64, 128))
    a = ap.parse_args()
    variants = [parse_variant(v) for v in a.variants.split(",")]
    a.out.mkdir(parents=True, exist_ok=True)
    data = load_patch_sets(a.data)
    pairs = validation_pairs([a.val])
    print(f"data: {', '.join(map(str, a.data))}; {a.epochs} x {a.steps} steps x {a.batch_size}; "
          f"validation: {a.val} ({len(pairs)} pairs)", flush=True)
    rows = []
    for mining, fraction in variants:
        subset = keep_fraction(data, fraction)
        weights = a.out / f"{mining}-{fraction:g}.pt"
        config = TrainConfig(epochs=a.epochs, steps_per_epoch=a.steps, batch_size=a.batch_size, mining=mining,
                             augment_photometric=True, seed=0, net=GeoPatchConfig(channels=tuple(a.channels)))
        start = time.perf_counter()
        history = train(subset, weights, config, device="cpu", progress=False)
        minutes = (time.perf_counter() - start) / 60
        score = validation_score(load_network(weights)[0], pairs, torch.device("cpu"))
        rows.append((f"{mining} @ {fraction:g}", len(subset), len(np.unique(subset.ids)), minutes,
                     history["loss"][-1], score))
        print(f"{rows[-1][0]}: val MS {score:.4f} ({minutes:.1f} min)", flush=True)
    print("| variant | patches | surface points | training time | final loss | val MS |\n|---|---|---|---|---|---|")
    for label, n_patches, n_points, minutes, loss, score in rows:
        print(f"| {label} | {n_patches} | {n_points} | {minutes:.1f} min | {loss:.3f} | {score:.3f} |")


if __name__ == "__main__":
    main()
