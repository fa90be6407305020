"""Validation matching score of GeoPatch weight files on held-out simulated sequences, with the same
pairs and scoring as `geofeat train`'s per-epoch validation (protocol "detect", 1024 SIFT keypoints,
two pairs per sequence, depth profile picked by "auto"), so that trained variants and the shipped
weights are compared on equal terms.

    PYTHONPATH=src .venv/bin/python benchmarks/val_score.py out/sim/val WEIGHTS.pt [...] [--shipped]
"""

from __future__ import annotations

import argparse

import torch

from geofeat.descriptors.geopatch import load_network
from geofeat.train.dataset import validation_pairs
from geofeat.train.loop import validation_score


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("val", help="folder of validation sequences")
    ap.add_argument("weights", nargs="*", help="GeoPatch weight files")
    ap.add_argument("--shipped", action="store_true", help="also score the shipped weights")
    a = ap.parse_args()
    pairs = validation_pairs([a.val])
    names = (["shipped"] if a.shipped else []) + list(a.weights)
    for name in names:
        net, _ = load_network(None if name == "shipped" else name)
        print(f"{name}: validation MS {validation_score(net, pairs, torch.device('cpu')):.4f} ({len(pairs)} pairs)",
              flush=True)


if __name__ == "__main__":
    main()
