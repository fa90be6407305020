"""Heat-method polar patches (the paper's "Heatflow" row) against the straightest-geodesic walk
(`geofeat.polar_patches`) on the shipped real Kinect frame: time and sample agreement.

Run: python benchmarks/bench_heat.py
"""

from __future__ import annotations

import time

import cv2
import numpy as np

import geofeat
from geofeat.geodesic.heat import HeatGeodesics, heat_polar_patches
from geofeat.io import demo_data_dir, read_landmarks


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def sift_keypoints(frame: geofeat.RGBDFrame, n: int = 250) -> np.ndarray:
    """The n strongest SIFT keypoints with depth under them, (n, 2) image pixels."""
    gray = (frame.image * 255).astype(np.uint8)
    kps = sorted(cv2.SIFT_create().detect(gray, None), key=lambda k: -k.response)
    xy = np.array([k.pt for k in kps], dtype=np.float64)
    # drop duplicates (SIFT repeats a location for several orientations)
    _, first = np.unique(np.round(xy, 2), axis=0, return_index=True)
    xy = xy[np.sort(first)]
    return xy[:n]


def compare(name: str, frame, mesh, kps: np.ndarray) -> None:
    walk, t_walk = timed(geofeat.polar_patches, frame, kps, mesh=mesh)
    hp, t_heat = timed(heat_polar_patches, frame, kps, mesh=mesh)
    both = walk.valid & hp.valid
    d = np.linalg.norm(walk.coords[both] - hp.coords[both], axis=-1)
    full = (walk.rings_reached[both] == 32).all(1) & (hp.rings_reached[both] == 32).all(1)
    print(f"{name}: {len(kps)} keypoints, valid walk {walk.valid.sum()} heat {hp.valid.sum()} both {both.sum()}")
    print(f"  time  walk {t_walk * 1e3:8.1f} ms   heat {t_heat * 1e3:8.1f} ms   heat/walk {t_heat / t_walk:6.1f}x"
          f"   (heat {t_heat / len(kps) * 1e3:.1f} ms per keypoint, incl. factorisation)")
    print(f"  sample disagreement (image px, keypoints valid in both): mean {d.mean():.2f}  median "
          f"{np.median(d):.2f}  p95 {np.percentile(d, 95):.2f}  max {d.max():.2f}")
    if full.any():
        print(f"    keypoints whose rays all reach the outer ring in both ({full.sum()}): mean "
              f"{d[full].mean():.2f} px")


def main() -> None:
    frame = geofeat.read_demo_frame()
    _, landmarks, visible = read_landmarks(demo_data_dir() / "cloud_1.csv")
    landmarks = landmarks[visible]
    mesh, t_mesh = timed(geofeat.build_mesh, frame)
    # warm up numba (compilation or cache load) outside the timings
    heat_polar_patches(frame, landmarks[:2], mesh=mesh)
    geofeat.polar_patches(frame, landmarks[:2], mesh=mesh)
    solver, t_fact = timed(HeatGeodesics, mesh)
    _, t_one = timed(solver.distance_maps, mesh.image_to_mesh(landmarks[:1]))
    Hm, Wm = mesh.points.shape[:2]
    print(f"frame {frame.shape[1]}x{frame.shape[0]}, mesh {Wm}x{Hm}, {len(solver.V)} vertices, "
          f"{len(solver.F)} faces; build_mesh {t_mesh * 1e3:.0f} ms")
    print(f"heat: t = {solver.t:.3g} m^2 (mean edge {solver.mean_edge * 1e3:.2f} mm); factorisation "
          f"{t_fact * 1e3:.0f} ms, one more source {t_one * 1e3:.1f} ms")
    compare("landmarks", frame, mesh, landmarks)
    compare("SIFT", frame, mesh, sift_keypoints(frame, 250))


if __name__ == "__main__":
    main()
