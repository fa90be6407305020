"""GeoPatch descriptor time for 2048 polar patches on CPU (1 and 2 torch threads, a few batch
sizes; and CUDA when available), next to OpenCV SIFT compute of the same 2048 keypoints measured in
the same run (best of interleaved repeats).
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
    frame = geofeat.read_demo_frame()
    kps = detect(frame, 2048, detector="sift", require_depth=False, contrast_threshold=0.001)
    patches = geofeat.polar_patches(frame, kps.xy)
    sift = cv2.SIFT_create()
    gray = to_uint8(frame.image)
    cv_kps = kps.to_cv()
    print(f"{len(kps)} keypoints of the Kinect frame ({patches.valid.sum()} valid patches); "
          f"OpenCV threads {cv2.getNumThreads()}")
    g = GeoPatch(device="cpu", backend="torch")  # the ONNX backends: benchmarks/bench_pipeline.py
    g.describe(patches.values[:64])
    for threads in (1, 2):
        torch.set_num_threads(threads)
        for batch in (64, 128, 512):
            g.batch_size = batch
            t_sift, t_ours = [], []
            for _ in range(3):
                t_sift.append(best_of(lambda: sift.compute(gray, cv_kps), 3))
                t_ours.append(best_of(lambda: g.describe(patches.values, patches.valid), 3))
            print(f"GeoPatch describe (cpu, {threads} torch threads, batch {batch:4d}) {min(t_ours) * 1000:8.1f} ms   "
                  f"OpenCV SIFT compute {min(t_sift) * 1000:7.1f} ms   ratio {min(t_ours) / min(t_sift):5.2f} (goal <= 1)")
    if torch.cuda.is_available():
        g = GeoPatch(device="cuda")
        g.describe(patches.values[:64])
        t = best_of(lambda: g.describe(patches.values, patches.valid))
        print(f"GeoPatch describe (cuda) {t * 1000:8.1f} ms")


if __name__ == "__main__":
    main()
