"""Make the ONNX models of a GeoPatch checkpoint: fp32 and static int8.

Run (rewrites the shipped models from the shipped weights):
    python benchmarks/make_geopatch_onnx.py
or for weights of your own (writes OUT.onnx and OUT_int8.onnx):
    python benchmarks/make_geopatch_onnx.py --weights runs/geopatch.pt --out runs/geopatch.onnx

The int8 model is calibrated on polar patches of simulated Kinect-noise frames (4 sequences x 3
frames, deform and rotate scenes, fixed seeds; never on the Kinect frame the tests check it on).
Prints how close both are to torch on the shipped Kinect frame. Needs torch, onnx, onnxruntime.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import geofeat
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.descriptors.geopatch_onnx import (ONNX_INT8_NAME, ONNX_NAME, calibration_patches, data_path,
                                               export_checkpoint, quantize_int8)
from geofeat.keypoints import detect


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--weights", default=None, help="GeoPatch .pt checkpoint (default: the shipped one)")
    parser.add_argument("--out", default=None, help="fp32 .onnx to write (default: geofeat/data/geopatch.onnx); "
                        "the int8 model goes next to it as NAME_int8.onnx")
    parser.add_argument("--calibration", choices=("minmax", "percentile", "entropy"), default="minmax")
    parser.add_argument("--sequences", type=int, default=4, help="simulated calibration sequences")
    args = parser.parse_args()
    out = data_path(ONNX_NAME) if args.out is None else Path(args.out)
    out_int8 = data_path(ONNX_INT8_NAME) if args.out is None else out.with_name(out.stem + "_int8.onnx")
    export_checkpoint(args.weights, out)
    patches = calibration_patches(n_sequences=args.sequences)
    print(f"calibration: {len(patches)} polar patches of simulated frames")
    quantize_int8(out, out_int8, patches, method=args.calibration)
    print(f"wrote {out} ({out.stat().st_size / 1e3:.0f} kB) and {out_int8} ({out_int8.stat().st_size / 1e3:.0f} kB)")

    frame = geofeat.read_demo_frame()
    p = geofeat.polar_patches(frame, detect(frame, 2048, detector="sift"))
    ref = GeoPatch(weights=args.weights, device="cpu", backend="torch").describe(p.values, p.valid)[p.valid]
    for name, path in (("fp32", out), ("int8", out_int8)):
        d = GeoPatch(weights=str(path), backend="onnx").describe(p.values, p.valid)[p.valid]
        cos = (d * ref).sum(1)
        print(f"{name}: max |d - torch| {np.abs(d - ref).max():.2e}; cosine to torch mean {cos.mean():.4f} "
              f"min {cos.min():.4f} ({len(d)} Kinect patches)")


if __name__ == "__main__":
    main()
