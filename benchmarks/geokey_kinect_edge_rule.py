"""Which part of GeoKey's edge rule (`geokey.candidates`, DEPTH_EDGE_MARGIN_PX) costs keypoints on the
shipped Kinect frame: the roll test of `geokey_kinect_roll.py` (GeoKey + GeoPatch, 2048 keypoints, means
over rolls of 30, 90 and 150 degrees) with the edge distance replaced by variants of it. Every variant
also drops candidates whose rounded pixel has no measured depth.

    PYTHONPATH=src python benchmarks/geokey_kinect_edge_rule.py
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

import geofeat
from common import roll_pair_scores
from geofeat.depth import fill_holes
from geofeat.detectors import geokey
from geofeat.detectors.cues import depth_edge_distance
from geofeat.frame import roll_camera

N = 2048


def _distance_to(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32 distance, pixels, to the nearest True pixel of `mask` (H, W)."""
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)


def steps(depth: np.ndarray, fx: float, k: float) -> np.ndarray:
    """(H, W) bool: steps of more than `k` footprints between 4-neighbours that both have depth."""
    d = np.asarray(depth, np.float32)
    fp = np.where(d > 0, d / np.float32(fx), np.float32(1.0))
    edge = np.zeros(d.shape, bool)
    both = (d[:, 1:] > 0) & (d[:, :-1] > 0)
    edge[:, :-1] |= both & (np.abs(d[:, 1:] - d[:, :-1]) / fp[:, :-1] > k)
    both = (d[1:] > 0) & (d[:-1] > 0)
    edge[:-1] |= both & (np.abs(d[1:] - d[:-1]) / fp[:-1] > k)
    return edge


VARIANTS: dict[str, Callable[[np.ndarray, float, float], np.ndarray]] = {
    "v3.4: steps and holes of the raw depth": depth_edge_distance,
    "steps and holes of fill_holes(depth)": lambda d, fx, k: depth_edge_distance(fill_holes(d), fx, k),
    "holes only": lambda d, fx, k: _distance_to(d <= 0),
    "steps only": lambda d, fx, k: _distance_to(steps(d, fx, k)),
    "no edge rule": lambda d, fx, k: np.full(d.shape, np.inf, np.float32),
}


def main() -> None:
    f0 = geofeat.read_demo_frame()
    describe = geofeat.make_descriptor("geopatch").compute
    rolls = [roll_camera(f0, angle) for angle in (30, 90, 150)]
    original = geokey.depth_edge_distance
    try:
        for name, distance in VARIANTS.items():
            # 0 on pixels without measured depth: no candidate there, whatever the variant
            geokey.depth_edge_distance = lambda d, fx, k, g=distance: np.where(d > 0, g(d, fx, k), 0.0)
            rows = [roll_pair_scores(f0, f1, A, describe, "geokey", N) for f1, A in rolls]
            r = np.mean(rows, axis=0)
            print(f"{name}: MS {r[0]:.3f} correct {r[1]:.0f} kps {r[2]:.0f}/{r[3]:.0f}", flush=True)
    finally:
        geokey.depth_edge_distance = original


if __name__ == "__main__":
    main()
