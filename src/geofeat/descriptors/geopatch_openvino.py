"""GeoPatch inference through OpenVINO's CPU plugin, two backends:

- "openvino-bf16": the float32 model `geofeat/data/geopatch.onnx` run in bfloat16 (AMX or
  AVX512-BF16), on CPUs that report BF16 support. The patches are z-scored in float32 here before
  the network sees them: the model's own z-score, run in bfloat16 on raw intensities, loses most of
  their precision (x - mean with 8 mantissa bits), and moved descriptors by up to 0.25 (minimum
  cosine to float32 0.75). On z-scored input the model's z-score is an identity, and the
  descriptors stay within cosine 0.9999 of torch's float32. On the 2-core development machine
  (Sapphire Rapids, AMX) it describes the Kinect frame's 1916 GeoKey patches in about 35 ms with 2
  threads (two streams), z-score included, against about 50 ms for "openvino-int8"
  (BENCHMARKS.md, "GeoPatch in bfloat16").
- "openvino-int8": the same int8 ONNX model as the "onnx-int8" backend.

OpenVINO reads `geofeat/data/geopatch_int8.onnx` (QDQ: int8 weights, uint8 activations) directly,
fuses the quantise / dequantise pairs into int8 convolutions (VNNI / AMX where the CPU has them),
and keeps everything else in float32 (`INFERENCE_PRECISION_HINT = f32`: on CPUs with bf16 support
its default would run the float parts, the input z-score included, in bf16, which moved the
descriptors by up to 0.19 in tests). On the 2-core development machine it describes the Kinect
frame's 2030 patches in 49 ms with 2 threads against 121 ms for ONNX Runtime on the same model
(idle machine, load 0.3; BENCHMARKS.md, "GeoPatch through OpenVINO").

Both need the `openvino` package (`pip install 'geofeat[fast]'`); without it GeoPatch falls back to
ONNX Runtime.
"""

from __future__ import annotations

import importlib.util
import json
import os
import threading
from functools import lru_cache
from pathlib import Path

import numpy as np

from numba import njit, prange

from ..inputs import check_threads
from .geopatch_onnx import default_threads, run_in_batches


def openvino_available() -> bool:
    """True when the openvino package can be imported."""
    return importlib.util.find_spec("openvino") is not None


@lru_cache(maxsize=1)
def cpu_has_bf16() -> bool:
    """True when openvino is installed and its CPU plugin reports bfloat16 support."""
    if not openvino_available():
        return False
    import openvino as ov

    try:
        return "BF16" in ov.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES")
    except RuntimeError:  # no CPU plugin, or a build that cannot say: take the int8 model
        return False


@njit(parallel=True, cache=True)
def _zscore_rows(x, out):
    """out[i] = (x[i] - mean) / (unbiased std + 1e-6) per row of x (N, M), sums in float64."""
    n, m = x.shape
    for i in prange(n):
        s = 0.0
        for j in range(m):
            s += x[i, j]
        mean = s / m
        q = 0.0
        for j in range(m):
            d = x[i, j] - mean
            q += d * d
        scale = 1.0 / (np.sqrt(q / max(m - 1, 1)) + 1e-6)
        for j in range(m):
            out[i, j] = (x[i, j] - mean) * scale


def zscore_patches(x: np.ndarray) -> np.ndarray:
    """(N, R, A) patches -> (N, R, A) float32, each patch minus its mean, divided by its
    standard deviation (unbiased) + 1e-6: the network's input normalisation
    (`GeoPatchNet.normalise`), in float64 sums."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    out = np.empty_like(x)
    if x.size:
        _zscore_rows(x.reshape(len(x), -1), out.reshape(len(x), -1))
    return out


@lru_cache(maxsize=8)
def _compile(path: str, mtime_ns: int, size: int, threads: int, bf16: bool, pid: int):
    """(compiled model, ONNX metadata) of a GeoPatch .onnx file; cached, since compiling takes
    30-60 ms and `geofeat.extract` makes a new GeoPatch for every frame. The file's time and size are
    in the key, so a rewritten file is compiled again, and so is the process id: a forked worker
    (the bench's process pool) compiles its own instead of using its parent's, whose inference
    threads it does not have."""
    import openvino as ov

    core = ov.Core()
    try:
        network = core.read_model(path)
    except RuntimeError as error:  # a corrupt file: the ValueError ONNX Runtime's backends give
        from ..inputs import error_summary

        raise ValueError(f"weights: {path} is not a GeoPatch ONNX model ({error_summary(error)})") from None
    # the ONNX metadata written by make_geopatch_onnx.py, which OpenVINO keeps under "framework"
    metadata = {key: network.get_rt_info(["framework", key]).astype(str)
                for key in ("config", "source_sha256") if network.has_rt_info(["framework", key])}
    if "config" not in metadata:
        raise ValueError(f"weights: {path} is not a GeoPatch ONNX model (no 'config' metadata)")
    # with several threads, one stream per thread, each batch run by one of them (`OpenVinoGeoPatch.run`):
    # 29-31 ms against 34-35 ms for one stream of two threads (bf16, 1916 patches, BENCHMARKS.md)
    mode = {"PERFORMANCE_HINT": "THROUGHPUT", "NUM_STREAMS": threads} if threads > 1 else {"PERFORMANCE_HINT": "LATENCY"}
    compiled = core.compile_model(network, "CPU", {
        "INFERENCE_NUM_THREADS": threads,
        "INFERENCE_PRECISION_HINT": "bf16" if bf16 else "f32",
        **mode,
    })
    return compiled, metadata


class OpenVinoGeoPatch:
    """A GeoPatch ONNX model compiled by OpenVINO for the CPU: `run((N, R, A) float32) -> (N, dim)`.

    Args:
        model: path to a GeoPatch .onnx file (made by benchmarks/make_geopatch_onnx.py).
        threads: inference threads (None: `default_threads()`, the usable cores, at most 4).
        bf16: run the float parts in bfloat16, the input z-scored in float32 first (for the float32
            model, on a CPU with BF16 support; elsewhere OpenVINO runs float32); False: float32.
    """

    def __init__(self, model: str | Path, threads: int | None = None, bf16: bool = False) -> None:
        self.bf16 = bool(bf16)
        self.threads = default_threads() if threads is None else check_threads(threads)
        path = Path(model).resolve()
        stat = path.stat()
        self.compiled, metadata = _compile(str(path), stat.st_mtime_ns, stat.st_size, self.threads, self.bf16,
                                           os.getpid())
        self.metadata = dict(metadata)
        self.config = json.loads(metadata["config"])
        # one request per instance (requests are not shared); with several threads, one per stream.
        # A request runs one inference at a time ("Infer Request is busy" otherwise), so calls of
        # one instance from several threads (a GeoPatch shared by a node's callbacks) take turns
        self.request = self.compiled.create_infer_request()
        self._busy = threading.Lock()
        self.queue = None
        if self.threads > 1:
            import openvino as ov

            self.queue = ov.AsyncInferQueue(self.compiled, self.threads)
            self.queue.set_callback(_copy_out)

    def run(self, x: np.ndarray, batch_size: int = 256) -> np.ndarray:
        """(N, R, A) float32 patches -> (N, dim) float32 unit descriptors, `batch_size` at a time
        (the batches spread over the streams when there are several)."""
        if self.bf16:
            x = zscore_patches(x)
        with self._busy:
            if self.queue is None or len(x) <= batch_size:
                # the request reuses its output buffer: copy each batch's descriptors out of it
                return run_in_batches(lambda b: np.array(self.request.infer({0: b})[0], copy=True), x, batch_size)
            x = np.ascontiguousarray(x, dtype=np.float32)
            out = np.empty((len(x), int(self.config["dim"])), np.float32)
            for start in range(0, len(x), batch_size):
                self.queue.start_async({0: x[start:start + batch_size]}, (out, start))
            self.queue.wait_all()
            return out


def _copy_out(request, userdata) -> None:
    """AsyncInferQueue callback: copy a finished batch's descriptors into out[start:]."""
    out, start = userdata
    result = request.get_output_tensor(0).data
    out[start:start + len(result)] = result
