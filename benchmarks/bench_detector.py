"""GeoKey's detection time against OpenCV SIFT's detection on the same frame, in one process.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_detector.py [--sequence out/difficulty/hard/deform-0]

Frames: the shipped Kinect frame (640 x 480) and, when given, the reference frame of a simulated
sequence. Both detectors return 2048 keypoints (SIFT: the protocol's `nfeatures=2048,
contrastThreshold=0.004`; GeoKey: the shipped weights). Best of 7 runs after a warm-up. The load
average is printed: a ratio measured on a loaded machine is not trustworthy.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

import geofeat
from geofeat.detectors.cues import cue_maps
from geofeat.detectors.geokey import candidates, detect_geokey, load_geokey

from common import best_of


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequence", default=None, help="a simulated sequence folder (its reference frame is timed too)")
    ap.add_argument("-n", type=int, default=2048)
    args = ap.parse_args()
    frames = {"kinect (640x480)": geofeat.read_demo_frame()}
    if args.sequence:
        seq = geofeat.read_sequence(args.sequence)
        frames[f"{seq.name} ({seq.frame(0).shape[1]}x{seq.frame(0).shape[0]})"] = seq.frame(seq.reference)
    model = load_geokey()
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}, cores: {os.cpu_count()}")
    print("| frame | SIFT detect (ms) | GeoKey detect (ms) | ratio | of which candidates | cue maps |")
    print("|---|---|---|---|---|---|")
    for name, frame in frames.items():
        detect_geokey(frame, args.n, model)
        t_sift = best_of(lambda: geofeat.detect(frame, args.n, detector="sift", keypoint_set="protocol"), 7)
        t_geokey = best_of(lambda: detect_geokey(frame, args.n, model), 7)
        t_cand = best_of(lambda: candidates(frame), 7)
        t_maps = best_of(lambda: cue_maps(frame, model.uses_depth_cues), 7)
        print(f"| {name} | {t_sift * 1e3:.1f} | {t_geokey * 1e3:.1f} | {t_geokey / t_sift:.2f} | "
              f"{t_cand * 1e3:.1f} | {t_maps * 1e3:.1f} |")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
