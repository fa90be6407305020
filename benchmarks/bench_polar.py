"""Speed of the geodesic mapping f(.) on the real Kinect frame, next to OpenCV SIFT in the same run.

Prints, against OpenCV SIFT detect+compute of 2048 keypoints measured in the same run (best of
interleaved repeats): depth preprocessing + mesh; f(.) (walk + projection + sampling) of 2048 SIFT
keypoints with the mesh given; f(.) on a fresh frame (preprocessing + mesh + walk); both again with
the full-resolution ('clean') depth profile.
Run: .venv/bin/python benchmarks/bench_polar.py
"""

from __future__ import annotations

import os
import platform

import cv2
import numpy as np

from common import best_of

import geofeat
from geofeat.depth import DepthConfig
from geofeat.geodesic.mesh import build_mesh

#: The full-resolution ('clean') depth profile.
CLEAN = DepthConfig(fill="idw", smooth_levels=0, mesh_scale=1.0)




def main() -> None:
    frame = geofeat.read_demo_frame()
    gray = np.clip(frame.image * 255 + 0.5, 0, 255).astype(np.uint8)
    sift = cv2.SIFT_create(nfeatures=2048, contrastThreshold=0.004)
    kps = sorted(sift.detect(gray, None), key=lambda k: -k.response)
    xy = np.array([k.pt for k in kps], dtype=np.float64)
    mesh = build_mesh(frame)
    clean_mesh = build_mesh(frame, CLEAN)
    geofeat.polar_patches(frame, xy[:10], mesh=mesh)  # compile / load the numba cache

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, numba threads "
          f"{__import__('numba').get_num_threads()}")
    print(f"frame 640x480 (real Kinect), mesh {mesh.points.shape[1]}x{mesh.points.shape[0]}")
    # interleave ours and the reference a few times: the best of each shares any background load
    t_sift, t_pre, t_map, t_fresh, t_clean, t_clean_fresh = [], [], [], [], [], []
    for _ in range(3):
        t_sift.append(best_of(lambda: sift.detectAndCompute(gray, None), 3))
        t_pre.append(best_of(lambda: build_mesh(frame), 3))
        t_map.append(best_of(lambda: geofeat.polar_patches(frame, xy, mesh=mesh), 3))
        # a fresh frame: depth preprocessing + mesh + walk (a new mesh every call, no cache)
        t_fresh.append(best_of(lambda: geofeat.polar_patches(frame, xy, mesh=build_mesh(frame)), 3))
        t_clean.append(best_of(lambda: geofeat.polar_patches(frame, xy, mesh=clean_mesh), 3))
        t_clean_fresh.append(best_of(lambda: geofeat.polar_patches(frame, xy, mesh=build_mesh(frame, CLEAN)), 3))
    sift_t = min(t_sift)
    P = geofeat.polar_patches(frame, xy, mesh=mesh)
    print(f"OpenCV SIFT detect+compute 2048                   {sift_t * 1000:8.1f} ms")
    print(f"depth preprocessing + mesh                        {min(t_pre) * 1000:8.1f} ms")
    print(f"f(.) {len(xy)} SIFT keypoints, mesh reused           {min(t_map) * 1000:8.1f} ms   "
          f"({P.valid.mean():.1%} valid)  ratio to SIFT {min(t_map) / sift_t:5.2f} (goal <= 0.5)")
    print(f"f(.) fresh frame (preprocessing + mesh + walk)    {min(t_fresh) * 1000:8.1f} ms   "
          f"ratio to SIFT {min(t_fresh) / sift_t:5.2f} (goal <= 1.0)")
    print(f"clean profile (full-resolution mesh {clean_mesh.points.shape[1]}x{clean_mesh.points.shape[0]}):")
    print(f"  f(.), mesh reused                               {min(t_clean) * 1000:8.1f} ms   "
          f"ratio to SIFT {min(t_clean) / sift_t:5.2f}")
    print(f"  f(.), fresh frame                               {min(t_clean_fresh) * 1000:8.1f} ms   "
          f"ratio to SIFT {min(t_clean_fresh) / sift_t:5.2f}")


if __name__ == "__main__":
    main()
