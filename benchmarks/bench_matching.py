"""GeoBit extraction and matching speed against OpenCV's brute-force Hamming matcher.

Run: python benchmarks/bench_matching.py [--repeats 7] [--threads N]

Prints, in one run (median of the repeats, after a warm-up call that compiles the numba kernels):
- GeoBit `describe` time for 2048 keypoints given their polar patches (16 rotations x 512 tests);
- `match` of 2048 x 2048 GeoBit descriptors with the min-over-16-rotations Hamming distance, as
  `match` runs it (method "auto") and through each search method: "blocked" (the one-pass pruned
  kernel, the only one before issue 21) and "two-stage" (bounds for all pairs, then exact distances
  only where they can matter), for plain nearest neighbours, the ratio test (0.8) and the mutual
  check; each checked equal to "blocked";
- OpenCV `cv2.BFMatcher(cv2.NORM_HAMMING).match` on 2048 x 2048 descriptors of 64 bytes (one
  rotation), and the ratio ours / OpenCV (goal: <= 2, although ours does 16 times the work).
Each line carries the 1-minute load average; timings are the best of 3 interleaved rounds of
the median of the repeats.
Descriptors are the real GeoBit descriptors of the demo Kinect frame against its 90-degree rolled
copy (SIFT keypoints, padded with random ones if fewer than 2048), and uniformly random bytes.
"""

from __future__ import annotations

import argparse
import os
import platform

import cv2
import numba
import numpy as np

from common import wall_times

import geofeat
from geofeat.descriptors.geobit import GeoBit
from geofeat.keypoints import detect
from geofeat.matching import _finish_matches, _hamming_search, match

N = 2048


def median_time(fn, repeats: int) -> float:
    return float(np.median(wall_times(fn, repeats, warm=1)))


def keypoints(frame, rng) -> np.ndarray:
    kp = detect(frame, n=N, detector="sift").xy
    if len(kp) < N:
        H, W = frame.shape
        ys, xs = np.nonzero(frame.depth[8:-8, 8:-8] > 0)
        pick = rng.choice(len(xs), N - len(kp), replace=False)
        kp = np.concatenate([kp, np.stack([xs[pick] + 8.0, ys[pick] + 8.0], axis=1)])
    return kp


def main() -> None:
    parser = argparse.ArgumentParser(description="GeoBit / matching speed")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--threads", type=int, default=None,
                        help="numba and OpenCV threads (default: their own defaults)")
    args = parser.parse_args()
    if args.threads:
        numba.set_num_threads(args.threads)
        cv2.setNumThreads(args.threads)
    rng = np.random.default_rng(0)
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    print(f"CPU: {cpu}; {os.cpu_count()} logical cores; numba threads {numba.get_num_threads()}; "
          f"OpenCV {cv2.__version__} threads {cv2.getNumThreads()}")

    frame = geofeat.read_demo_frame()
    rolled = frame.rotated90(1)
    gb = GeoBit()
    p0 = geofeat.polar_patches(frame, keypoints(frame, rng))
    p1 = geofeat.polar_patches(rolled, keypoints(rolled, rng))
    t_desc = median_time(lambda: gb.describe(p0.values, p0.valid), args.repeats)
    f0, f1 = gb.compute(frame, p0.keypoints, patches=p0), gb.compute(rolled, p1.keypoints, patches=p1)
    print(f"GeoBit describe, {N} keypoints x 16 rotations x 512 tests: {1e3 * t_desc:8.1f} ms")

    random0 = rng.integers(0, 256, (N, 16, 64), dtype=np.uint8)
    random1 = rng.integers(0, 256, (N, 16, 64), dtype=np.uint8)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    for name, d0, d1, v0, v1 in (
        ("GeoBit (demo frame vs 90 deg roll)", f0.descriptors, f1.descriptors, f0.valid, f1.valid),
        ("random bytes", random0, random1, np.ones(N, bool), np.ones(N, bool)),
    ):
        a0, a1 = np.ascontiguousarray(d0[:, 0]), np.ascontiguousarray(d1[:, 0])
        F0 = geofeat.features.Features(np.zeros((N, 2)), d0, v0)
        F1 = geofeat.features.Features(np.zeros((N, 2)), d1, v1)
        print(f"\n{name}:")
        for label, mutual, ratio in (("nearest neighbour", False, None), ("ratio test 0.8", False, 0.8),
                                     ("mutual check", True, None)):
            fns = {"match()": lambda: match(F0, F1, mutual=mutual, ratio=ratio),
                   "OpenCV": lambda: bf.match(a0, a1)}
            ref = _finish_matches(*_hamming_search(d0, d1, v0, v1, mutual, ratio, method="blocked"),
                                  ratio=ratio, mutual=mutual).matches0
            for method in ("blocked", "two-stage"):
                got = _finish_matches(*_hamming_search(d0, d1, v0, v1, mutual, ratio, method=method),
                                      ratio=ratio, mutual=mutual).matches0
                assert np.array_equal(got, ref), method
                fns[method] = (lambda method=method: _hamming_search(d0, d1, v0, v1, mutual, ratio, method=method))
            assert np.array_equal(match(F0, F1, mutual=mutual, ratio=ratio).matches0, ref)
            times = {k: [] for k in fns}
            for _ in range(3):  # interleave to share any background load fairly
                for k, fn in fns.items():
                    times[k].append(median_time(fn, args.repeats))
            best = {k: min(v) for k, v in times.items()}
            print(f"  {label} (matches equal across methods), load average {os.getloadavg()[0]:.2f}:")
            for k in ("blocked", "two-stage", "match()"):
                print(f"    ours {k:10s} {N} x {N} x 16 rotations: {1e3 * best[k]:8.1f} ms  "
                      f"ratio to OpenCV {best[k] / best['OpenCV']:5.2f}  (goal <= 2)")
            print(f"    OpenCV BFMatcher NORM_HAMMING, 1 rotation: {1e3 * best['OpenCV']:8.1f} ms")
        t_ours1, t_cv = [], []
        for _ in range(3):
            t_ours1.append(median_time(lambda: match(a0, a1), args.repeats))
            t_cv.append(median_time(lambda: bf.match(a0, a1), args.repeats))
        ours1, cv = min(t_ours1), min(t_cv)
        # sanity: our single-rotation matcher agrees with OpenCV's
        cv_idx = np.array([m.trainIdx for m in bf.match(a0, a1)])
        agree = (match(a0, a1).matches0 == cv_idx).mean()
        print(f"  ours, {N} x {N} x 1 rotation (hamming):        {1e3 * ours1:8.1f} ms, OpenCV {1e3 * cv:8.1f} ms "
              f"(agrees with ours on {100 * agree:.1f} % of queries), ratio {ours1 / cv:5.2f}, "
              f"load average {os.getloadavg()[0]:.2f}")

if __name__ == "__main__":
    main()
