"""The shipped Kinect frame against itself rolled by 30, 90 and 150 degrees (exact truth, `frame.roll_camera`):
GeoPatch MS, correct matches (< 3 px) and keypoints with SIFT and GeoKey, at 1024 and 2048 keypoints.

    PYTHONPATH=src python benchmarks/geokey_kinect_roll.py
"""
import numpy as np

import geofeat
from geofeat.frame import roll_camera
from geofeat.matching import match

f0 = geofeat.read_demo_frame()
d = geofeat.make_descriptor("geopatch")
for det in ("sift", "geokey"):
    for n in (1024, 2048):
        rows = []
        for ang in (30, 90, 150):
            f1, A = roll_camera(f0, ang)
            k0, k1 = geofeat.detect(f0, n, detector=det), geofeat.detect(f1, n, detector=det)
            truth = k0.xy @ A[:, :2].T + A[:, 2]
            H, W = f1.shape
            inside = (truth[:, 0] >= 0) & (truth[:, 0] < W) & (truth[:, 1] >= 0) & (truth[:, 1] < H)
            m = match(d.compute(f0, k0), d.compute(f1, k1)).matches0
            ok = (m >= 0) & inside
            correct = np.zeros(len(k0), bool)
            correct[ok] = np.linalg.norm(k1.xy[m[ok]] - truth[ok], axis=1) < 3
            rows.append([correct.sum() / min(inside.sum(), len(k1)), correct.sum(), len(k0), len(k1)])
        r = np.mean(rows, axis=0)
        print(f"{det} n={n}: MS {r[0]:.3f} correct {r[1]:.0f} kps {r[2]:.0f}/{r[3]:.0f}", flush=True)
