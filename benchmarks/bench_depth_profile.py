"""The "auto" depth profile's cost per fresh frame: `geofeat.depth_profile`, which stops at the cheap
tests, against the same rule applied to the whole `geofeat.depth_noise` (what it cost before), in
one process. Both must give the same profile; the script checks it.

    PYTHONPATH=src python benchmarks/bench_depth_profile.py [SEQUENCE_FOLDER ...]

Frames: the shipped Kinect frame, and the reference frame of each sequence folder given.
"""

from __future__ import annotations

import argparse
import os
import time

import geofeat
from geofeat.depth import MIN_NOISE_WINDOWS, SLOPE_NOISE_THRESHOLD, STEP_THRESHOLD, depth_noise, depth_profile
from geofeat.io import read_sequence


def full_rule(frame) -> str:
    """The profile from every statistic of `depth_noise`: the reference."""
    noise = depth_noise(frame.depth, frame.K)
    if noise.windows < MIN_NOISE_WINDOWS or noise.slope_noise > SLOPE_NOISE_THRESHOLD:
        return "kinect"
    return "quantised" if noise.step_per_footprint > STEP_THRESHOLD else "clean"


def best_ms(fn, repeats: int) -> float:
    """Best wall time of `repeats` calls, milliseconds."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequences", nargs="*", help="sequence folders (their reference frames are timed too)")
    ap.add_argument("--repeats", type=int, default=20)
    a = ap.parse_args()
    frames = {"kinect (shipped)": geofeat.read_demo_frame()}
    for folder in a.sequences:
        seq = read_sequence(folder)
        frames[folder] = seq.frame(seq.reference)  # the folder: two sets can hold one sequence name
    print(f"load average {os.getloadavg()}")
    print("| frame | profile | depth_profile (ms) | rule on the whole depth_noise (ms) | ratio |\n|---|---|---|---|---|")
    for name, frame in frames.items():
        profile = depth_profile(frame)
        if profile != full_rule(frame):
            raise SystemExit(f"{name}: depth_profile says {profile}, the full rule {full_rule(frame)}")
        fast, full = best_ms(lambda: depth_profile(frame), a.repeats), best_ms(lambda: full_rule(frame), a.repeats)
        print(f"| {name} | {profile} | {fast:.1f} | {full:.1f} | {fast / full:.2f} |")
    print(f"load average at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()
