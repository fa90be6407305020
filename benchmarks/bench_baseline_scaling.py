"""Which keypoint size and angle each OpenCV baseline needs: correct-match rate of the same SIFT
keypoints on the Kinect image vs a copy rotated by 45 deg and a copy scaled by 0.6, for several
size factors, with and without SIFT's angle. Every keypoint counts: one that OpenCV drops on either
side (valid = False, as near the border at large factors) is a miss, as in the matching score.
The rigid pairs measure scale and rotation invariance only; the BRISK / FREAK factor was chosen by
matching score on held-out simulated sequences (see geofeat/descriptors/baselines.py).
Run: .venv/bin/python benchmarks/bench_baseline_scaling.py
"""

from __future__ import annotations

import cv2
import numpy as np

import geofeat
from geofeat.descriptors.baselines import BASELINES, OpenCVDescriptor
from geofeat.keypoints import Keypoints, detect
from geofeat.matching import match


def warped_pair(angle_deg: float, scale: float):
    frame = geofeat.read_demo_frame()
    H, W = frame.shape
    A = cv2.getRotationMatrix2D(((W - 1) / 2, (H - 1) / 2), angle_deg, scale)
    img = cv2.warpAffine(frame.image, A, (W, H), flags=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    depth = np.ones((H, W), np.float32)
    f0, f1 = geofeat.RGBDFrame(frame.image, depth, frame.K), geofeat.RGBDFrame(img, depth, frame.K)
    k0 = detect(f0, 500, detector="sift", require_depth=False, border_px=40)
    xy1 = k0.xy @ A[:, :2].T + A[:, 2]
    inside = (xy1[:, 0] > 40) & (xy1[:, 0] < W - 40) & (xy1[:, 1] > 40) & (xy1[:, 1] < H - 40)
    k0 = k0[inside]
    k1 = Keypoints(xy1[inside], (k0.angles - angle_deg) % 360, k0.sizes * scale, k0.responses)
    return f0, f1, k0, k1


def rate(name, factor, use_angle, f0, f1, k0, k1) -> float:
    d = OpenCVDescriptor(name, use_angle=use_angle, size_factor=factor)
    F0, F1 = d.compute(f0, k0), d.compute(f1, k1)
    m = match(F0, F1)
    return float((m.matches0 == np.arange(len(k0))).mean()) if len(k0) else 0.0


def main() -> None:
    pairs = {"rot45": warped_pair(45.0, 1.0), "scale0.6": warped_pair(0.0, 0.6)}
    factors = (1.0, 2.0, 4.0, 6.0, 8.0, 12.0)
    print("correct-match rate (same keypoints, nearest neighbour) by size factor x SIFT size")
    print(f"{'descriptor':10s} {'pair':9s} {'angle':5s} " + " ".join(f"x{f:<5g}" for f in factors))
    for name in BASELINES:
        for pair_name, pair in pairs.items():
            for use_angle in (True, False):
                rates = [rate(name, f, use_angle, *pair) for f in factors]
                print(f"{name:10s} {pair_name:9s} {str(use_angle):5s} " + " ".join(f"{r:6.2f}" for r in rates))


if __name__ == "__main__":
    main()
