"""GeoPatch descriptor time for 2048 polar patches on CPU (2 threads; and CUDA when available),
next to OpenCV SIFT compute of the same 2048 keypoints in the same run.
Run: .venv/bin/python benchmarks/bench_geopatch.py
"""

from __future__ import annotations


import cv2
import torch

from common import best_of

import geofeat
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.keypoints import detect, to_uint8




def main() -> None:
    torch.set_num_threads(2)
    frame = geofeat.read_demo_frame()
    kps = detect(frame, 2048, require_depth=False, contrast_threshold=0.001)
    patches = geofeat.polar_patches(frame, kps.xy)
    sift = cv2.SIFT_create()
    gray = to_uint8(frame.image)
    cv_kps = kps.to_cv()
    t_sift = best_of(lambda: sift.compute(gray, cv_kps))
    print(f"{len(kps)} keypoints of the Kinect frame ({patches.valid.sum()} valid patches)")
    print(f"OpenCV SIFT compute                 {t_sift * 1000:8.1f} ms")
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices:
        g = GeoPatch(device=device)
        g.describe(patches.values[:64])
        t = best_of(lambda: g.describe(patches.values, patches.valid))
        print(f"GeoPatch describe ({device}, {torch.get_num_threads()} threads) {t * 1000:8.1f} ms   "
              f"ratio to SIFT {t / t_sift:.2f}   (goal <= 150 ms)")


if __name__ == "__main__":
    main()
