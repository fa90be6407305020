"""The shipped Kinect frame against itself rolled by 30, 90 and 150 degrees (exact truth, `frame.roll_camera`):
GeoPatch MS, correct matches (< 3 px) and keypoints with SIFT and GeoKey, at 1024 and 2048 keypoints.

    PYTHONPATH=src python benchmarks/geokey_kinect_roll.py
"""
import numpy as np

import geofeat
from common import roll_pair_scores
from geofeat.frame import roll_camera

f0 = geofeat.read_demo_frame()
d = geofeat.make_descriptor("geopatch")
for det in ("sift", "geokey"):
    for n in (1024, 2048):
        rows = [roll_pair_scores(f0, *roll_camera(f0, ang), d.compute, det, n) for ang in (30, 90, 150)]
        r = np.mean(rows, axis=0)
        print(f"{det} n={n}: MS {r[0]:.3f} correct {r[1]:.0f} kps {r[2]:.0f}/{r[3]:.0f}", flush=True)
