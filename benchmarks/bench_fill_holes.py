"""Hole filling (`geofeat.depth.fill_holes`) on the shipped Kinect frame, against OpenCV's labelling
alone in the same process, and optionally against another version of geofeat.

Run: PYTHONPATH=src .venv/bin/python benchmarks/bench_fill_holes.py [--previous OLD/src] [--repeats 50]

`--previous`: the src/ folder of another checkout (e.g. `git archive 05a3f34 src | tar x -C /tmp/old`);
its `geofeat/depth.py` is loaded beside this one, both are timed in turn, and their outputs compared.
Prints the best of `repeats` calls of each, in ms, and the 1-minute load average.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys

import cv2
import numpy as np

import geofeat
from geofeat.depth import fill_holes

from common import best_of


def best_ms(fn, repeats: int) -> float:
    fn()  # warm-up: numba's compiled code loads on the first call
    return best_of(fn, repeats) * 1e3


def load_previous(src: str):
    """`geofeat/depth.py` of another checkout's src/, as a module of its own."""
    spec = importlib.util.spec_from_file_location("geofeat.previous_depth", os.path.join(src, "geofeat", "depth.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look the module up while it loads
    spec.loader.exec_module(module)
    return module


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--previous", default=None, help="src/ folder of another geofeat to time beside this one")
    ap.add_argument("--repeats", type=int, default=50)
    a = ap.parse_args()
    depth = geofeat.read_demo_frame().depth
    missing = (depth <= 0).astype(np.uint8)
    print(f"load average {os.getloadavg()[0]:.2f}; Kinect frame {depth.shape[1]}x{depth.shape[0]}, "
          f"{missing.mean():.1%} missing; OpenCV threads {cv2.getNumThreads()}")
    rows = [("fill_holes (this version)", lambda: fill_holes(depth)),
            ("OpenCV connectedComponents", lambda: cv2.connectedComponents(missing, connectivity=4, ltype=cv2.CV_32S)),
            ("OpenCV connectedComponentsWithStats",
             lambda: cv2.connectedComponentsWithStats(missing, connectivity=4, ltype=cv2.CV_32S))]
    if a.previous:
        previous = load_previous(a.previous)
        same = np.array_equal(previous.fill_holes(depth), fill_holes(depth))
        print(f"previous version's output bit-identical: {same}")
        rows.insert(1, ("fill_holes (previous version)", lambda: previous.fill_holes(depth)))
    for _ in range(2):  # two interleaved rounds
        for name, fn in rows:
            print(f"  {name:<38} {best_ms(fn, a.repeats):7.3f} ms", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
