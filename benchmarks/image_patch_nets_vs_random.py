"""Matching score of the shipped tfeat-sim / logpolar-sim weights against a random-weight net of the
same architecture, on held-out simulated pairs (protocol "detect", the training loop's validation).

Run: PYTHONPATH=src python benchmarks/image_patch_nets_vs_random.py out/sim/val [--keypoints 1024]
"""

from __future__ import annotations

import argparse

import torch

from geofeat.descriptors.image_patch_nets import ARCHS, ImagePatchDescriptor
from geofeat.train.imagepatches import image_validation_pairs
from geofeat.train.loop import validation_score


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequences", nargs="+")
    parser.add_argument("--keypoints", type=int, default=1024)
    args = parser.parse_args()
    print("| net | shipped weights MS | random weights MS |\n|---|---|---|")
    for arch in ARCHS:
        pairs = image_validation_pairs(args.sequences, arch, n_keypoints=args.keypoints)
        ms = [validation_score(ImagePatchDescriptor(arch, weights=w).net, pairs, torch.device("cpu"))
              for w in (None, "random")]
        print(f"| {arch}-sim | {ms[0]:.3f} | {ms[1]:.3f} |")


if __name__ == "__main__":
    main()
