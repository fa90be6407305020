"""GeoPatch inference through ONNX Runtime (fp32, and int8 with static quantisation).

The graph (`build_model`) is written node by node from the batch-norm-folded torch network, so
that it is the same computation as `GeoPatchNet` in eval mode:

    (N, R, A) patches -> per-patch z-score (unbiased std, + 1e-6) -> [circular pad on the angle
    axis (Slice + Concat) | conv | ReLU | (max-pool 2x2)] x 3 -> max over angle -> Gemm -> L2

The z-score stays a separate step at the input: the first convolution has one input channel, so
the z-score touches R*A = 1024 values per patch against the 0.7 M multiply-adds of that
convolution; folding it into the convolution would move a per-patch affine map onto its
28 x 32 x C1 outputs instead, which costs more, not less.

`geofeat/data/geopatch.onnx` (fp32) and `geofeat/data/geopatch_int8.onnx` (QDQ, per-channel int8
weights, uint8 activations, calibrated on polar patches of simulated Kinect-noise frames) are made
from `geofeat/data/geopatch.pt` by `benchmarks/make_geopatch_onnx.py`. Both carry the SHA-256 of
the checkpoint they come from (metadata `source_sha256`). Running them needs only numpy and
onnxruntime; making them needs torch (to read the checkpoint) and onnx.
"""

from __future__ import annotations

import hashlib
import json
import os
from importlib import resources
from pathlib import Path

import numpy as np

from ..inputs import check_threads

#: Backends of `GeoPatch(backend=...)`.
BACKENDS = ("torch", "onnx", "onnx-int8", "openvino-int8", "openvino-bf16")
#: Environment variable that overrides the default backend.
BACKEND_ENV = "GEOFEAT_GEOPATCH_BACKEND"
#: File names inside geofeat/data.
ONNX_NAME = "geopatch.onnx"
ONNX_INT8_NAME = "geopatch_int8.onnx"
OPSET = 17
INPUT, OUTPUT = "patches", "descriptors"
#: Nodes that stay in float in the int8 model (input z-score, output L2 normalisation).
FLOAT_NODES = ("z_mean", "z_sub", "z_sumsq", "z_var", "z_std", "z_den", "z_div", "z_unsq",
               "l2_norm", "l2_clip", "l2_div")


def check_backend(backend: str) -> str:
    """The backend name (lower case), or ValueError naming the accepted ones."""
    key = backend.strip().lower() if isinstance(backend, str) else backend
    if key not in BACKENDS:
        raise ValueError(f"backend: unknown GeoPatch backend {backend!r}; expected one of {', '.join(BACKENDS)}"
                         f" (or unset {BACKEND_ENV})")
    return key


def data_path(name: str) -> Path:
    return Path(str(resources.files("geofeat") / "data" / name))


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def onnx_available() -> bool:
    """onnxruntime is installed (not imported here)."""
    import importlib.util

    return importlib.util.find_spec("onnxruntime") is not None


# ------------------------------------------------------------------------------------------------
# export (needs torch and onnx)

def network_layers(net) -> tuple[list[tuple], dict]:
    """The layers of a GeoPatchNet as numpy: [("conv", W, b, pad), ("relu",), ("pool",), ...] with
    batch norm folded in, plus the head {"W", "b"}."""
    from .geopatch_net import CircularConv, MaxPool2x2, fuse_batchnorm
    import torch.nn as nn

    fused = fuse_batchnorm(net).eval()
    layers = []
    for layer in fused.features:
        if isinstance(layer, CircularConv):
            layers.append(("conv", layer.conv.weight.detach().cpu().numpy().astype(np.float32),
                           layer.conv.bias.detach().cpu().numpy().astype(np.float32), layer.pad))
        elif isinstance(layer, nn.ReLU):
            layers.append(("relu",))
        elif isinstance(layer, MaxPool2x2):
            layers.append(("pool",))
        else:
            raise TypeError(f"GeoPatchNet layer {type(layer).__name__} has no ONNX translation")
    head = {"W": fused.head.weight.detach().cpu().numpy().astype(np.float32),
            "b": fused.head.bias.detach().cpu().numpy().astype(np.float32)}
    return layers, head


def build_model(layers: list[tuple], head: dict, config: dict, metadata: dict | None = None):
    """An onnx.ModelProto computing GeoPatchNet.forward on (N, R, A) float32 patches."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    R, A = int(config["n_rings"]), int(config["n_angles"])
    nodes, inits = [], []

    def const(name, value, dtype=np.float32):
        if name not in {t.name for t in inits}:
            inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def node(op, inputs, name, **attrs):
        nodes.append(helper.make_node(op, inputs, [name], name=name, **attrs))
        return name

    # per-patch z-score, as GeoPatchNet.normalise: (x - mean) / (std_unbiased + 1e-6)
    mean = node("ReduceMean", [INPUT], "z_mean", axes=[1, 2], keepdims=1)
    d = node("Sub", [INPUT, mean], "z_sub")
    ss = node("ReduceSumSquare", [d], "z_sumsq", axes=[1, 2], keepdims=1)
    var = node("Div", [ss, const("n_minus_1", R * A - 1)], "z_var")
    std = node("Sqrt", [var], "z_std")
    den = node("Add", [std, const("z_eps", 1e-6)], "z_den")
    z = node("Div", [d, den], "z_div")
    x = node("Unsqueeze", [z, const("axis1", [1], np.int64)], "z_unsq")

    const("zero", [0], np.int64)
    const("axis3", [3], np.int64)
    const("int_max", [np.iinfo(np.int64).max], np.int64)
    for i, layer in enumerate(layers):
        if layer[0] == "conv":
            _, W, b, pad = layer
            if pad:  # circular padding of the angle axis: last `pad` columns | x | first `pad` columns
                left = node("Slice", [x, const(f"m{pad}", [-pad], np.int64), "int_max", "axis3"], f"pad{i}_left")
                right = node("Slice", [x, "zero", const(f"p{pad}", [pad], np.int64), "axis3"], f"pad{i}_right")
                x = node("Concat", [left, x, right], f"pad{i}", axis=3)
            x = node("Conv", [x, const(f"conv{i}_W", W), const(f"conv{i}_b", b)], f"conv{i}",
                     kernel_shape=list(W.shape[2:]))
        elif layer[0] == "relu":
            x = node("Relu", [x], f"relu{i}")
        else:
            x = node("MaxPool", [x], f"pool{i}", kernel_shape=[2, 2], strides=[2, 2])
    if config.get("angle_pool", True):
        x = node("ReduceMax", [x], "angle_max", axes=[3], keepdims=0)
    x = node("Flatten", [x], "flatten", axis=1)
    x = node("Gemm", [x, const("head_W", head["W"]), const("head_b", head["b"])], "head", transB=1)
    # F.normalize: x / max(||x||, 1e-12)
    norm = node("ReduceL2", [x], "l2_norm", axes=[1], keepdims=1)
    norm = node("Max", [norm, const("l2_eps", 1e-12)], "l2_clip")
    nodes.append(helper.make_node("Div", [x, norm], [OUTPUT], name="l2_div"))

    dim = int(head["W"].shape[0])
    graph = helper.make_graph(
        nodes, "geopatch",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["N", R, A])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["N", dim])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="geofeat")
    model.ir_version = 8  # readable by onnxruntime >= 1.14
    meta = {"config": json.dumps(config), **(metadata or {})}
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, str(value)
    onnx.checker.check_model(model)
    return model


def export_checkpoint(weights: str | Path | None = None, out: str | Path | None = None):
    """The fp32 ONNX model of a GeoPatch checkpoint (None = the shipped weights); written to `out`
    when given. Needs torch and onnx."""
    from dataclasses import asdict

    from .geopatch import default_weights_path
    from .geopatch_net import load_network

    path = default_weights_path() if weights is None else Path(weights)
    net, _ = load_network(path)
    layers, head = network_layers(net)
    config = asdict(net.config)
    config["channels"] = list(config["channels"])
    model = build_model(layers, head, config, {"source": path.name, "source_sha256": file_sha256(path)})
    if out is not None:
        import onnx

        onnx.save(model, str(out))
    return model


def calibration_patches(n_sequences: int = 4, n_frames: int = 3, n_keypoints: int = 1024,
                        seed: int = 1000) -> np.ndarray:
    """(N, R, A) float32 polar patches of simulated Kinect-noise frames (deform and rotate scenes,
    fixed seeds, packaged textures), for the static int8 calibration. Valid patches only."""
    import tempfile

    from ..geodesic.polar import polar_patches
    from ..io import read_sequence
    from ..keypoints import detect
    from ..sim import simulate_sequence

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n_sequences):
            folder = simulate_sequence(Path(tmp) / f"s{i}", scenario=("deform", "rotate")[i % 2], n_frames=n_frames,
                                       seed=seed + i, kinect_noise=True, progress=False)
            seq = read_sequence(folder)
            for name in seq.names:
                frame = seq.frame(name)
                kps = detect(frame, n_keypoints, detector="sift")
                p = polar_patches(frame, kps)
                out.append(p.values[p.valid])
    return np.concatenate(out).astype(np.float32)


def quantize_int8(fp32_path: str | Path, out: str | Path, patches: np.ndarray, method: str = "minmax",
                  batch: int = 256) -> None:
    """Static int8 quantisation (QDQ; int8 per-channel weights, uint8 activations) of the fp32
    model at `fp32_path`, calibrated on `patches` (N, R, A); the z-score and the L2 normalisation
    stay in float. method: "minmax", "percentile" or "entropy"."""
    import onnx
    from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType,
                                          quantize_static)

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.chunks = iter([{INPUT: patches[i:i + batch]} for i in range(0, len(patches), batch)])

        def get_next(self):
            return next(self.chunks, None)

    methods = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
               "entropy": CalibrationMethod.Entropy}
    quantize_static(str(fp32_path), str(out), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                    calibrate_method=methods[method], nodes_to_exclude=list(FLOAT_NODES))
    model = onnx.load(str(out))  # keep the provenance of the fp32 model, and say how it was made
    src = {p.key: p.value for p in onnx.load(str(fp32_path)).metadata_props}
    src.update(quantisation=f"static QDQ, int8 per-channel weights, uint8 activations, {method} calibration on "
               f"{len(patches)} polar patches of simulated Kinect-noise frames")
    del model.metadata_props[:]
    for key, value in src.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, str(out))


# ------------------------------------------------------------------------------------------------
# inference (numpy + onnxruntime only)

def default_threads() -> int:
    """ORT intra-op threads: the cores this process may run on, at most 4 (the network is small:
    more threads spend their time waiting on each other)."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        n = os.cpu_count() or 1
    return max(1, min(4, n))


class OnnxGeoPatch:
    """A GeoPatch ONNX model in an onnxruntime CPU session: `run((N, R, A) float32) -> (N, dim)`.

    Args:
        model: path to a .onnx file, or its bytes.
        threads: intra-op threads (None: `default_threads()`).
        spin: let idle ORT threads spin (lower latency on an idle machine, CPU burnt under load).
    """

    def __init__(self, model: str | Path | bytes, threads: int | None = None, spin: bool = False) -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = default_threads() if threads is None else check_threads(threads)
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin else "0")
        self.threads = opts.intra_op_num_threads
        try:
            self.session = ort.InferenceSession(model if isinstance(model, bytes) else str(model), opts,
                                                providers=["CPUExecutionProvider"])
            meta = self.session.get_modelmeta().custom_metadata_map
            self.metadata = dict(meta)
            self.config = json.loads(meta["config"])
        except Exception as error:  # noqa: BLE001 - a corrupt file or another network: one user error
            where = "the exported model" if isinstance(model, bytes) else str(model)
            from ..inputs import error_summary

            raise ValueError(f"weights: {where} is not a GeoPatch ONNX model ({error_summary(error)})") from None

    def run(self, x: np.ndarray, batch_size: int = 256) -> np.ndarray:
        """(N, R, A) float32 patches -> (N, dim) float32 unit descriptors, `batch_size` at a time."""
        return run_in_batches(lambda b: self.session.run([OUTPUT], {INPUT: b})[0], x, batch_size)


def run_in_batches(infer, x: np.ndarray, batch_size: int) -> np.ndarray:
    """`infer` ((B, R, A) float32 -> (B, dim)) over (N, R, A) patches, `batch_size` at a time, the
    outputs stacked into one (N, dim) float32 array (the runtimes' `run`)."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    if len(x) <= batch_size:
        return np.asarray(infer(x), np.float32)
    return np.concatenate([np.asarray(infer(x[s:s + batch_size]), np.float32) for s in range(0, len(x), batch_size)])
