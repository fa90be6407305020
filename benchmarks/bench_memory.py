"""Peak memory of the whole GeoBit and GeoPatch pipelines on a 1920x1080 RGB-D frame with 2048
keypoints (goal: under 2 GB each).

Each pipeline runs in its own process: read nothing from disk, build a synthetic full-HD frame
(textured image, wavy depth with a hole), detect 2048 SIFT keypoints, compute the descriptors
(depth preprocessing, mesh, f(.), descriptor) on it and on its 90-degree roll, and match the two.
Prints the resident memory after the imports and the peak resident memory (ru_maxrss) of the process.
Run: python benchmarks/bench_memory.py
"""

from __future__ import annotations

import subprocess
import sys

PIPELINE = """
import resource, sys, numpy as np, cv2
import geofeat
if sys.argv[1] == "geopatch":
    import torch
def rss_mb():
    with open("/proc/self/status") as fh:
        return next(int(l.split()[1]) for l in fh if l.startswith("VmRSS")) / 1024
after_imports = rss_mb()
H, W = 1080, 1920
K = np.array([[1050.0, 0, 959.5], [0, 1050.0, 539.5], [0, 0, 1.0]])
rng = np.random.default_rng(0)
image = cv2.GaussianBlur(rng.random((H, W)).astype(np.float32), (0, 0), 2.0)
image = (image - image.min()) / (image.max() - image.min())
v, u = np.mgrid[0:H, 0:W]
depth = (1.2 + 0.08 * np.sin(u / 90.0) * np.cos(v / 70.0)).astype(np.float32)
depth[500:540, 900:960] = 0  # a hole to fill
frame = geofeat.RGBDFrame(image, depth, K)
rolled = frame.rotated90(1)
desc = geofeat.make_descriptor(sys.argv[1])
k0, k1 = geofeat.detect(frame, 2048, detector="sift"), geofeat.detect(rolled, 2048, detector="sift")
f0, f1 = desc.compute(frame, k0), desc.compute(rolled, k1)
m = geofeat.match(f0, f1)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(f"{sys.argv[1]:8s}: {len(k0)} + {len(k1)} keypoints, {int((m.matches0 >= 0).sum())} matches; "
      f"RSS after imports {after_imports:6.0f} MB, peak {peak:6.0f} MB (goal < 2048 MB)")
"""


def main() -> None:
    print("1920x1080 RGB-D frame, 2048 SIFT keypoints, describe the frame and its 90-degree roll, match:")
    for name in ("geobit", "geopatch"):
        out = subprocess.run([sys.executable, "-c", PIPELINE, name], capture_output=True, text=True)
        if out.returncode != 0:
            print(f"{name}: failed\n{out.stderr[-2000:]}")
            continue
        print(out.stdout.strip())


if __name__ == "__main__":
    main()
