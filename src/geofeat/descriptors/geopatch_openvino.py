"""GeoPatch inference through OpenVINO: the same int8 ONNX model as the "onnx-int8" backend, run by
OpenVINO's CPU plugin (backend "openvino-int8").

OpenVINO reads `geofeat/data/geopatch_int8.onnx` (QDQ: int8 weights, uint8 activations) directly,
fuses the quantise / dequantise pairs into int8 convolutions (VNNI / AMX where the CPU has them),
and keeps everything else in float32 (`INFERENCE_PRECISION_HINT = f32`: on CPUs with bf16 support
its default would run the float parts, the input z-score included, in bf16, which moved the
descriptors by up to 0.19 in tests). On the 2-core development machine it describes the Kinect
frame's 2030 patches in 49 ms with 2 threads against 121 ms for ONNX Runtime on the same model
(idle machine, load 0.3; BENCHMARKS.md, "GeoPatch through OpenVINO").

Needs the `openvino` package (`pip install 'geofeat[fast]'`); without it GeoPatch falls back to
ONNX Runtime.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

from .geopatch_onnx import default_threads, run_in_batches


def openvino_available() -> bool:
    """True when the openvino package can be imported."""
    return importlib.util.find_spec("openvino") is not None


class OpenVinoGeoPatch:
    """A GeoPatch ONNX model compiled by OpenVINO for the CPU: `run((N, R, A) float32) -> (N, dim)`.

    Args:
        model: path to a GeoPatch .onnx file (made by benchmarks/make_geopatch_onnx.py).
        threads: inference threads (None: `default_threads()`, the usable cores, at most 4).
    """

    def __init__(self, model: str | Path, threads: int | None = None) -> None:
        import openvino as ov

        self.threads = default_threads() if threads is None else int(threads)
        core = ov.Core()
        network = core.read_model(str(model))
        # the ONNX metadata written by make_geopatch_onnx.py, which OpenVINO keeps under "framework"
        self.metadata = {key: network.get_rt_info(["framework", key]).astype(str)
                         for key in ("config", "source_sha256") if network.has_rt_info(["framework", key])}
        if "config" not in self.metadata:
            raise ValueError(f"weights: {model} is not a GeoPatch ONNX model (no 'config' metadata)")
        self.config = json.loads(self.metadata["config"])
        self.compiled = core.compile_model(network, "CPU", {
            "INFERENCE_NUM_THREADS": self.threads,
            "PERFORMANCE_HINT": "LATENCY",
            "INFERENCE_PRECISION_HINT": "f32",
        })
        self.request = self.compiled.create_infer_request()

    def run(self, x: np.ndarray, batch_size: int = 256) -> np.ndarray:
        """(N, R, A) float32 patches -> (N, dim) float32 unit descriptors, `batch_size` at a time."""
        # the request reuses its output buffer: copy each batch's descriptors out of it
        return run_in_batches(lambda b: np.array(self.request.infer({0: b})[0], copy=True), x, batch_size)
