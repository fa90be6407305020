"""Speed of the geodesic mapping f(.) on the real Kinect frame, next to OpenCV SIFT in the same run.

Prints: depth preprocessing + mesh time; f(.) (walk + projection + sampling) for 250 and 2048 SIFT
keypoints; OpenCV SIFT detect+compute of 2048 keypoints; the ratio f(2048) / SIFT.
Run: .venv/bin/python benchmarks/bench_polar.py
"""

from __future__ import annotations

import os
import platform

import cv2
import numpy as np

from common import best_of

import geofeat
from geofeat.geodesic.mesh import build_mesh




def main() -> None:
    frame = geofeat.read_demo_frame()
    gray = np.clip(frame.image * 255 + 0.5, 0, 255).astype(np.uint8)
    sift = cv2.SIFT_create(nfeatures=2048, contrastThreshold=0.004)
    kps = sorted(sift.detect(gray, None), key=lambda k: -k.response)
    xy = np.array([k.pt for k in kps], dtype=np.float64)
    mesh = build_mesh(frame)
    geofeat.polar_patches(frame, xy[:10], mesh=mesh)  # compile / load the numba cache

    t_pre = best_of(lambda: build_mesh(frame))
    t_sift = best_of(lambda: sift.detectAndCompute(gray, None))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, numba threads "
          f"{__import__('numba').get_num_threads()}")
    print(f"frame 640x480 (real Kinect), mesh {mesh.points.shape[1]}x{mesh.points.shape[0]}")
    print(f"depth preprocessing + mesh            {t_pre * 1000:8.1f} ms")
    results = {}
    for n in (250, 2048):
        sub = xy[:n]
        t = best_of(lambda: geofeat.polar_patches(frame, sub, mesh=mesh))
        results[n] = t
        P = geofeat.polar_patches(frame, sub, mesh=mesh)
        print(f"f(.) {len(sub):5d} SIFT keypoints            {t * 1000:8.1f} ms   ({P.valid.mean():.1%} valid)")
    print(f"OpenCV SIFT detect+compute 2048        {t_sift * 1000:8.1f} ms")
    print(f"ratio f(2048) / SIFT                   {results[2048] / t_sift:8.2f}   (goal < 0.5)")
    t_all = best_of(lambda: geofeat.polar_patches(frame, xy))
    print(f"preprocessing + f(.) 2048 together     {t_all * 1000:8.1f} ms")


if __name__ == "__main__":
    main()
