"""GeoPatch through OpenVINO at each model and inference precision, against torch float32.

Run: PYTHONPATH=src .venv/bin/python benchmarks/bench_openvino_precision.py [--repeats 5]

The shipped Kinect frame, 2048 SIFT keypoints. For the int8 and float32 ONNX models, inference
precision f32 or bf16 (and f16 for the float32 model), raw patches or patches z-scored in float32
first (what backend "openvino-bf16" does), 1 and 2 threads: best wall time of `--repeats` calls, and
the minimum and mean cosine of the descriptors to torch's float32 ones. Prints the load average: a
timing taken while it exceeds 1.5 is not an idle-machine figure. bf16 runs as f32 where the CPU has
no bfloat16 (then the bf16 rows only repeat the f32 ones).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import openvino as ov

import geofeat
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.descriptors.geopatch_onnx import ONNX_INT8_NAME, ONNX_NAME, data_path
from geofeat.descriptors.geopatch_openvino import zscore_patches
from geofeat.keypoints import detect


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--batch", type=int, default=256)
    a = ap.parse_args()
    frame = geofeat.read_demo_frame()
    p = geofeat.polar_patches(frame, detect(frame, 2048, detector="sift"))
    raw = p.values[p.valid].astype(np.float32)
    ref = GeoPatch(device="cpu", backend="torch").describe(raw)
    core = ov.Core()
    print(f"{len(raw)} patches; CPU capabilities {core.get_property('CPU', 'OPTIMIZATION_CAPABILITIES')}; "
          f"load average {os.getloadavg()}")
    print(f"{'model':20s} {'precision':9s} {'input':9s} {'threads':>7s} {'ms':>7s} {'min cos':>8s} {'mean cos':>9s} {'load':>5s}")
    runs = [(m, prec) for m in (ONNX_INT8_NAME, ONNX_NAME) for prec in ("f32", "bf16")] + [(ONNX_NAME, "f16")]
    for model, prec in runs:
        for zscored in (False, True):
            x = zscore_patches(raw) if zscored else raw
            for threads in (1, 2):
                compiled = core.compile_model(core.read_model(str(data_path(model))), "CPU", {
                    "INFERENCE_NUM_THREADS": threads, "PERFORMANCE_HINT": "LATENCY",
                    "INFERENCE_PRECISION_HINT": prec})
                request = compiled.create_infer_request()

                def run():
                    return np.concatenate([np.array(request.infer({0: x[s:s + a.batch]})[0], copy=True)
                                           for s in range(0, len(x), a.batch)])

                cosine = (run() * ref).sum(1)
                times = []
                for _ in range(a.repeats):
                    t = time.perf_counter()
                    run()
                    times.append(time.perf_counter() - t)
                print(f"{model:20s} {prec:9s} {'z-scored' if zscored else 'raw':9s} {threads:7d} "
                      f"{1e3 * min(times):7.1f} {cosine.min():8.4f} {cosine.mean():9.5f} {os.getloadavg()[0]:5.2f}",
                      flush=True)


if __name__ == "__main__":
    main()
