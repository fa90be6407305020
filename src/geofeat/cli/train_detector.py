"""`geofeat train-detector`: train GeoKey, the learned keypoint detector."""

from __future__ import annotations

import argparse

import numpy as np

from .options import keypoint_count, number_at_least, whole_number


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `train-detector` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("train-detector", help="train GeoKey, the learned keypoint detector, on simulated sequences")
    p.add_argument("--data", nargs="+", required=True, help="simulated sequence folders, or folders of them")
    p.add_argument("--val", nargs="+", required=True, help="held-out simulated sequences (choose the NMS radius, level bias and score threshold)")
    p.add_argument("--out", required=True, help="weights file to write (e.g. geokey.pt; an .npz archive)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT file")
    p.add_argument("--keypoints", type=keypoint_count, nargs="+", default=(1024, 2048),
                   help="keypoints per frame for validation; the scorer and NMS radius with the best mean MS "
                        "over these counts are kept (default 1024 2048)")
    p.add_argument("--hidden", type=whole_number(1), nargs="+", default=(32, 32), help="hidden layer widths (default 32 32)")
    p.add_argument("--steps", type=whole_number(1), default=3000, help="Adam steps (default 3000)")
    p.add_argument("--seed", type=whole_number(0, 2**64 - 1), default=0, help="random seed (default 0)")
    p.add_argument("--denoise", type=number_at_least(0.0), default=0.0,
                   help="detect on the image through an edge-preserving (bilateral) filter whose range is this many "
                        "times the frame's noise level, in training and in the weights written (default 0: none)")
    p.add_argument("--labels", choices=("repeatable", "matchable"), default="repeatable",
                   help="training labels: found again within 1 px (default), or also matched by GeoPatch (slower)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Train GeoKey and print its validation table."""
    from ..outputs import refuse_input_folder
    from ..train.detector import SIFT_KEY, train_detector

    counts = tuple(args.keypoints)
    twice = sorted({n for n in counts if counts.count(n) > 1})
    if twice:  # scored once, yet the last line said "at 1024, 1024 keypoints per frame"
        raise ValueError(f"--keypoints: {', '.join(map(str, twice))} given twice; name each count once")
    refuse_input_folder(args.out, [*args.data, *(args.val or ())])  # the weights among the training sequences
    model, results, chosen = train_detector(args.data, args.val, args.out, n=counts, hidden=tuple(args.hidden),
                                    steps=args.steps, seed=args.seed, labels=args.labels, denoise=args.denoise,
                                    overwrite=args.overwrite, names=("--data", "--val"))
    print("| scorer | NMS radius (px) | keypoints | GeoPatch MS | MMA | repeatability | correct matches / pair "
          "| reference keypoints / frame |")
    print("|---|---|---|---|---|---|---|---|")
    for key, per_count in results.items():
        name, radius = key
        mark = " (chosen)" if key == chosen else ""
        for n, r in per_count.items():
            print(f"| {name}{mark} | {'-' if key == SIFT_KEY else f'{radius:g}'} | {n} | {r['ms']:.3f} | "
                  f"{r['mma']:.3f} | {r['repeatability']:.3f} | {r['hits']:.0f} | {r['n_ref']:.0f} |")
    if np.isfinite(model.threshold):
        rule = (f"threshold {model.threshold:g}, floor: the best {100 * model.min_fraction:.0f} % of each frame's "
                "candidates")
    else:  # it said "threshold -inf, floor: the best 0 % of each frame's candidates"
        rule = "none did, so no score threshold"
    print(f"wrote {args.out} (chosen by the mean validation MS at {', '.join(map(str, counts))} keypoints per frame; "
          f"a score threshold only where it keeps at least SIFT's keypoints and correct matches; {rule})")
    return 0
