"""GeoPatch: a small CNN on geodesic polar patches (paper, "Geodesic-Guided Feature Learning").

Architecture (`GeoPatchNet`), for (B, 1, R = 32 rings, A = 32 angles) patches:

    per-patch z-score
    circular pad (angle) 2 | conv 5x5, 16 | BN | ReLU | max-pool 2x2      -> (16, 14, 16)
    circular pad (angle) 1 | conv 3x3, 32 | BN | ReLU | max-pool 2x2      -> (32, 6, 8)
    circular pad (angle) 1 | conv 3x3, 64 | BN | ReLU                     -> (64, 4, 8)
    max over the angle axis (rotation invariance)                         -> (64, 4)
    linear 256 -> 128, L2 normalisation                                   -> (128,)

TFeat-like and shallow, as in the paper, with circular padding on the angle axis before every
convolution and the paper's max-pool over angle before the fully connected layer (the authors'
shipped network has neither the angle max-pool nor this size: it flattens into an 854k-parameter
dense head). `GeoPatchConfig` defaults to half the paper's channels (16/32/64), the earlier
speed-first choice; the shipped weights (v9) use the paper's 32/64/128 (at equal training they
scored 0.227 against 0.204 on the `hard` test sequences) and cost 1.6x the half-width net (0.22 s for 2048 patches on 2
CPU threads); the checkpoint carries its own shape. See BENCHMARKS.md. `angle_pool=False` flattens
instead (the ablation without rotation invariance).

Trained weights ship in `geofeat/data/geopatch.pt` (trained by `geofeat train` on simulated
sequences; see the training notes in BENCHMARKS.md) and load offline.

Backends (`GeoPatch(backend=...)`, or the environment variable GEOFEAT_GEOPATCH_BACKEND): "torch"
(`geopatch_net.GeoPatchNet`; training, CUDA, user .pt weights), "onnx" (ONNX Runtime fp32, the
torch descriptors within 1e-4), "onnx-int8" (static int8: the same `geofeat bench` scores at about
2.3x less CPU than torch; `geopatch_onnx`), and through OpenVINO "openvino-int8" (the int8 model)
and "openvino-bf16" (the fp32 model in bfloat16; `geopatch_openvino`). The default for the shipped
weights on CPU is the fastest of these that the machine has (`resolve_backend`; BENCHMARKS.md).
This module imports no torch; the torch names below load it on first use.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache, partial
from importlib import resources
from pathlib import Path
from typing import Any

import importlib.util
import os
import warnings

import numpy as np

from ..constants import N_ANGLES, N_RINGS
from ..features import Features
from ..frame import RGBDFrame, check_frame, too_thin_to_describe
from ..keypoints import as_keypoints
from ..geodesic.mesh import GridMesh
from ..geodesic.polar import PolarPatches, check_depth_config, check_patches, polar_patches
from .settings import PatchSettings, merge_settings
from ..inputs import check_threads, check_weights_path, check_whole

#: File name of the shipped weights inside geofeat/data.
WEIGHTS_NAME = "geopatch.pt"


@dataclass(frozen=True)
class GeoPatchConfig:
    """Network shape. channels: output channels of the three convolutions; dim: descriptor size."""

    channels: tuple[int, int, int] = (16, 32, 64)
    dim: int = 128
    angle_pool: bool = True
    n_rings: int = N_RINGS
    n_angles: int = N_ANGLES


def default_weights_path() -> Path:
    return Path(str(resources.files("geofeat") / "data" / WEIGHTS_NAME))


#: Names defined in `geopatch_net` (torch), still importable from here; loaded on first use.
_TORCH_NAMES = ("CircularConv", "MaxPool2x2", "GeoPatchNet", "fuse_batchnorm", "save_checkpoint", "load_network")


def __getattr__(name: str):
    if name in _TORCH_NAMES:
        from . import geopatch_net

        return getattr(geopatch_net, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: The backend used for the shipped weights on CPU when none is asked for (the fastest one whose
#: descriptors are equivalent to torch's; BENCHMARKS.md, "GeoPatch through ONNX Runtime").
DEFAULT_BACKEND = "onnx-int8"
#: Patches per forward pass on CPU, per backend (BENCHMARKS.md).
DEFAULT_BATCH = {"torch": 128, "onnx": 256, "onnx-int8": 256, "openvino-int8": 128, "openvino-bf16": 128}


def _cuda_visible() -> bool:
    """A CUDA device torch can use. Imports torch only where an NVIDIA driver is present."""
    if importlib.util.find_spec("torch") is None or not os.path.exists("/proc/driver/nvidia/version"):
        return False
    import torch

    return torch.cuda.is_available()


_warned_no_onnxruntime = False


def _warn_no_onnxruntime() -> None:
    """Say once per process that the shipped weights run on torch because onnxruntime (a declared
    dependency) is missing: the default backend's descriptors differ from torch's by the int8 rounding."""
    global _warned_no_onnxruntime
    if _warned_no_onnxruntime:
        return
    _warned_no_onnxruntime = True
    from .geopatch_onnx import BACKEND_ENV

    warnings.warn(f"GeoPatch: onnxruntime is not installed, so the shipped weights run on torch instead of the "
                  f"default {DEFAULT_BACKEND} backend (slower; descriptors within the int8 rounding of the "
                  f"default's); pip install onnxruntime, or set {BACKEND_ENV}=torch to choose torch",
                  RuntimeWarning, stacklevel=3)


def resolve_backend(backend: str | None, weights: str | Path | None, device: str | None) -> str:
    """The backend GeoPatch uses: `backend` if given, else $GEOFEAT_GEOPATCH_BACKEND, else torch
    on a CUDA device, for user .pt weights, or without onnxruntime; "onnx" for .onnx weights;
    for the shipped weights on CPU "openvino-bf16" when openvino is installed and the CPU has
    bfloat16 support, "openvino-int8" when openvino is installed, else `DEFAULT_BACKEND`."""
    from .geopatch_onnx import BACKEND_ENV, check_backend, onnx_available

    if backend is None and os.environ.get(BACKEND_ENV, "").strip():
        backend = os.environ[BACKEND_ENV]
    onnx_weights = weights is not None and str(weights).lower().endswith(".onnx")
    if backend is not None:
        backend = check_backend(backend)
        if onnx_weights and backend == "torch":
            raise ValueError(f"backend: torch cannot run the ONNX weights {weights}; use backend='onnx'")
        return backend
    if onnx_weights:
        return "onnx"
    if (device is not None and str(device).split(":")[0] != "cpu") or (device is None and _cuda_visible()):
        return "torch"
    if weights is not None:
        return "torch"
    if not onnx_available():
        _warn_no_onnxruntime()
        return "torch"
    from .geopatch_openvino import cpu_has_bf16, openvino_available

    if not openvino_available():
        return DEFAULT_BACKEND
    return "openvino-bf16" if cpu_has_bf16() else "openvino-int8"


@dataclass(frozen=True)
class GeoPatchSettings(PatchSettings):
    """GeoPatch's options (with the polar patch settings of `PatchSettings`: radius, depth_config,
    blur_px). The network's architecture is `GeoPatchConfig`, read from the weights.

    Attributes:
        weights: checkpoint path (.pt, from `geofeat train`, or a .onnx file made from one by
            benchmarks/make_geopatch_onnx.py); None = the weights shipped with geofeat.
        device: "cpu", "cuda", ... (default: CUDA when available, through torch).
        batch_size: patches per forward pass on CPU (None: `DEFAULT_BATCH` of the backend; on CUDA
            at least 4096 patches go in one pass).
        threads: CPU threads for `describe` (1 to 64 per CPU): torch threads (set for the call, then
            restored; None keeps torch's setting) or ONNX Runtime intra-op threads (None: the usable
            cores, at most 4). On a machine shared with other busy processes 1 thread can be several times
            faster than 2 with torch (its OpenMP threads wait on each other; see BENCHMARKS.md).
        backend: "torch", "onnx" (ONNX Runtime, fp32: the torch descriptors within 1e-4),
            "onnx-int8" (ONNX Runtime, static int8 quantisation: close to torch's, the same
            matching scores; shipped weights only, or an int8 .onnx file), "openvino-int8" (the
            same int8 model run by OpenVINO, 2-2.5x faster on CPU; needs `geofeat[fast]`) or
            "openvino-bf16" (the fp32 model run by OpenVINO in bfloat16 on the float32-z-scored
            patches: within cosine 0.9999 of torch, faster than int8 on CPUs with AMX; shipped
            weights or an fp32 .onnx file). None: the environment variable
            GEOFEAT_GEOPATCH_BACKEND, else `resolve_backend`'s choice ("openvino-bf16" for the
            shipped weights on a CPU with bfloat16 support when openvino is installed,
            "openvino-int8" on other CPUs, "onnx-int8" without openvino). These backends run on
            CPU and do not import torch; "onnx" with user .pt weights exports them on the fly
            (needs torch and onnx).
    """

    weights: str | Path | None = None
    device: str | None = None
    batch_size: int | None = None
    threads: int | None = None
    backend: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        check_weights_path(self.weights)  # "" said "no GeoPatch checkpoint at ."


def _torch_network(weights, device) -> tuple:
    """(batch-norm-folded GeoPatchNet on `device`, checkpoint) of `weights` (None: the shipped ones):
    a copy of the one loaded and folded once per file and device (`_fused_network`). Loading and
    folding took about 8 ms per GeoPatch, which `geofeat.extract(..., device="cuda")` makes for every
    frame; a copy takes 1.5 ms, and no GeoPatch shares its network with another (the checkpoint's
    contents, read-only metadata and the unfolded weights, are shared)."""
    import copy

    from .geopatch_net import load_network

    path = default_weights_path() if weights is None else Path(weights)
    if not path.is_file():
        return load_network(weights)  # its error naming the file
    stat = path.stat()
    net, checkpoint = _fused_network(str(path.resolve()), stat.st_mtime_ns, stat.st_size, str(device))
    return copy.deepcopy(net), dict(checkpoint)


@lru_cache(maxsize=8)
def _fused_network(path: str, mtime_ns: int, size: int, device: str) -> tuple:
    """`_torch_network`'s cache: keyed on the file's time and size too, so that a rewritten file is
    loaded again."""
    from .geopatch_net import fuse_batchnorm, load_network

    net, checkpoint = load_network(path)
    return fuse_batchnorm(net).to(device), checkpoint


class GeoPatch:
    """GeoPatch descriptor extractor: polar patches -> GeoPatchNet -> (N, 128) float32 unit vectors
    (a `geofeat.descriptors.base.Descriptor`).

    Options: `GeoPatchSettings`, given and merged as `geofeat.descriptors.settings` says.
    """

    Settings = GeoPatchSettings

    def __init__(self, settings: GeoPatchSettings | Mapping[str, Any] | None = None, **kwargs: Any) -> None:
        self.settings = s = merge_settings(GeoPatchSettings, settings, kwargs)
        weights, device, batch_size, threads = s.weights, s.device, s.batch_size, s.threads
        # whole numbers only: 2.5 threads or "2" were truncated or converted without a word
        if batch_size is not None:
            check_whole(batch_size, "batch_size", 1)
        self.threads = None if threads is None else check_threads(threads)  # 100000 killed the process
        self.net = self.session = None
        self.checkpoint: dict = {}
        from .geopatch_onnx import BACKEND_ENV

        chosen_by_env = os.environ.get(BACKEND_ENV, "").strip() if s.backend is None else ""
        try:
            self._load(s.backend, weights, device)
        except ValueError as error:
            text = str(error)
            if not chosen_by_env or BACKEND_ENV in text or not (text.startswith("backend:") or "CPU only" in text):
                raise
            # a backend that cannot run these weights or on this device: its advice (backend='torch', ...) is for
            # a backend= argument, which was not given
            raise ValueError(f"{error} (the backend was chosen by the environment variable {BACKEND_ENV}="
                             f"{chosen_by_env}: set it to a backend that runs these weights on this device, or "
                             "unset it)") from None
        self.radius = s.radius
        self.name = "geopatch" if weights is None else f"geopatch={weights}"
        self.binary, self.metric, self.geodesic = False, "l2", True
        self.depth_config = s.depth_config
        self.blur_px = s.blur_px
        self.batch_size = int(DEFAULT_BATCH[self.backend] if batch_size is None else batch_size)

    def _load(self, backend: str | None, weights, device) -> None:
        """Set `backend` (`resolve_backend`), `device`, `config` and the network (`net`, `checkpoint`) or
        the runtime session (`session`) of the weights; ValueError naming what cannot run."""
        self.backend = resolve_backend(backend, weights, device)
        if self.backend == "torch":
            import torch

            from ..gpu import torch_device

            # `is None`, not falsy: device=0 (torch's cuda:0) or "" ran on the CPU without a word
            self.device = torch_device(device if device is not None else ("cuda" if torch.cuda.is_available() else "cpu"))
            self.net, self.checkpoint = _torch_network(weights, self.device)
            self.config = self.net.config
            return
        if device is not None and str(device).split(":")[0] != "cpu":
            raise ValueError(f"device: the {self.backend} backend runs on CPU only, got device={device!r}; "
                             "use backend='torch' for a GPU")
        self.device = "cpu"
        self.session = self._onnx_session(weights)
        cfg = dict(self.session.config)
        cfg["channels"] = tuple(cfg["channels"])
        self.config = GeoPatchConfig(**cfg)

    def _onnx_session(self, weights):
        from .geopatch_onnx import (ONNX_INT8_NAME, ONNX_NAME, OnnxGeoPatch, data_path, export_checkpoint,
                                    onnx_available)
        from .geopatch_openvino import OpenVinoGeoPatch, openvino_available

        int8 = self.backend in ("onnx-int8", "openvino-int8")
        if self.backend.startswith("openvino"):
            if not openvino_available():
                raise ValueError(f"backend: {self.backend} needs the openvino package (pip install 'geofeat[fast]'); "
                                 "or use backend='onnx-int8'")
            runtime = partial(OpenVinoGeoPatch, bf16=self.backend == "openvino-bf16")
        else:
            if not onnx_available():
                raise ValueError(f"backend: {self.backend} needs the onnxruntime package (pip install onnxruntime); "
                                 "or use backend='torch'")
            runtime = OnnxGeoPatch
        if weights is None:
            path = data_path(ONNX_INT8_NAME if int8 else ONNX_NAME)
            if not path.is_file():
                raise ValueError(f"backend: the {self.backend} model is missing from the package ({path}); "
                                 "rebuild it with benchmarks/make_geopatch_onnx.py or use backend='torch'")
            return runtime(path, threads=self.threads)
        if str(weights).lower().endswith(".onnx"):
            if not Path(weights).is_file():
                raise ValueError(f"weights: no GeoPatch ONNX model at {weights}")
            return runtime(weights, threads=self.threads)
        if self.backend == "openvino-bf16":
            raise ValueError(f"backend: openvino-bf16 runs an .onnx model; export {weights} with "
                             "benchmarks/make_geopatch_onnx.py --weights and pass the .onnx file, or use "
                             "backend='onnx' or 'torch'")
        if int8:
            raise ValueError(f"backend: {self.backend} needs a calibrated int8 model; make one from "
                             f"{weights} with benchmarks/make_geopatch_onnx.py --weights and pass the "
                             "_int8.onnx file as weights, or use backend='onnx' or 'torch'")
        if not Path(weights).is_file():
            raise ValueError(f"weights: no GeoPatch checkpoint at {weights}")
        if importlib.util.find_spec("onnx") is None:
            raise ValueError(f"backend: exporting {weights} for the onnx backend needs the onnx package "
                             "(pip install 'geofeat[onnx]'), or use backend='torch'")
        return OnnxGeoPatch(export_checkpoint(weights).SerializeToString(), threads=self.threads)

    def __repr__(self) -> str:
        return (f"GeoPatch(config={self.config}, backend={self.backend}, device={self.device}, "
                f"radius={self.radius})")

    def describe(self, patch_values: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
        """(N, R, A) polar patches -> (N, dim) float32 descriptors; rows of invalid patches are 0.
        Valid patches must be finite (ValueError otherwise)."""
        v = np.asarray(patch_values, dtype=np.float32)
        cfg = self.config
        if v.ndim != 3 or v.shape[1:] != (cfg.n_rings, cfg.n_angles):
            raise ValueError(f"patch_values: expected shape (N, {cfg.n_rings}, {cfg.n_angles}), got {v.shape}")
        n = v.shape[0]
        valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool).reshape(-1)
        if valid.shape != (n,):
            raise ValueError(f"valid: expected shape ({n},), got {valid.shape}")
        out = np.zeros((n, cfg.dim), np.float32)
        index = np.flatnonzero(valid)
        if len(index) == 0:
            return out
        x = np.ascontiguousarray(v[index])
        finite = np.isfinite(x).reshape(len(x), -1).all(axis=1)
        if not finite.all():  # torch gave NaN descriptors, the int8 backends finite ones that mean nothing
            raise ValueError(f"patch_values: NaN or infinite values in valid patches {index[~finite][:10].tolist()}; "
                             "mark them invalid (valid=False)")
        out[index] = self._describe_torch(x) if self.backend == "torch" else self.session.run(x, self.batch_size)
        return out

    def describe_tensor(self, values, valid=None, half: bool = False):
        """`describe` on torch tensors on the network's device (the GPU path, `geofeat.gpu`): (N, R, A)
        float32 patches -> (N, dim) float32 descriptor tensor, rows of invalid patches 0, nothing
        copied to the host. fp32 with TF32 off, so that descriptors equal the CPU's within 1e-4;
        `half=True` runs the network under float16 autocast on CUDA (faster, not equal: measured in
        benchmarks/bench_gpu.py)."""
        import torch

        if self.backend != "torch":
            raise ValueError(f"describe_tensor: needs the torch backend, not {self.backend}")
        cfg = self.config
        if values.ndim != 3 or tuple(values.shape[1:]) != (cfg.n_rings, cfg.n_angles):
            raise ValueError(f"values: expected shape (N, {cfg.n_rings}, {cfg.n_angles}), got {tuple(values.shape)}")
        from ..process_settings import no_tf32

        with no_tf32():
            autocast = torch.autocast("cuda", dtype=torch.float16, enabled=bool(half) and self.device.type == "cuda")
            with torch.inference_mode(), autocast:
                x = values.to(self.device, torch.float32).unsqueeze(1)
                batch = self.batch_size if self.device.type == "cpu" else max(self.batch_size, 4096)
                y = torch.cat([self.net(x[s:s + batch]) for s in range(0, len(x), batch)]) if len(x) else \
                    torch.zeros((0, cfg.dim), device=self.device)
                if valid is not None:
                    y = torch.where(valid.to(self.device).bool()[:, None], y, torch.zeros((), device=self.device))
                return y.float()

    def compute_cuda(self, frame: RGBDFrame, keypoints, mesh=None):
        """`compute` with the mesh (unless `mesh`, a host GridMesh or a `geofeat.gpu.DeviceMesh`, is
        given), walk, patch sampling and CNN on the GPU (`geofeat.gpu.compute_cuda`):
        `geofeat.gpu.DeviceFeatures` whose descriptors stay on the device."""
        from ..gpu import compute_cuda

        return compute_cuda(self, frame, keypoints, mesh=mesh)

    def _describe_torch(self, x: np.ndarray) -> np.ndarray:
        import torch

        from ..process_settings import torch_threads

        # one transfer each way: the patches to the device, the descriptors back (on CUDA the
        # per-batch copies and synchronisations would cost more than the network)
        with torch.inference_mode():
            t = torch.from_numpy(x).to(self.device).unsqueeze(1)
            batch = self.batch_size if self.device.type == "cpu" else max(self.batch_size, 4096)
            # torch's threads are the process's: set for the call, restored after it, also when
            # calls overlap in several threads (`process_settings`)
            with torch_threads(self.threads):
                y = torch.cat([self.net(t[start:start + batch]) for start in range(0, len(t), batch)])
            return y.float().cpu().numpy()

    def compute(self, frame: RGBDFrame, keypoints, patches: PolarPatches | None = None,
                mesh: GridMesh | None = None) -> Features:
        """GeoPatch features of `keypoints` ((N, 2) pixels, cv2.KeyPoint list or `Keypoints`). `patches`:
        precomputed `polar_patches` of these keypoints on this frame with the descriptor's radius,
        `blur_px` and `depth_config`; `mesh`: a prebuilt mesh of the frame of its `depth_config`
        (ValueError otherwise)."""
        kps = as_keypoints(keypoints, check_frame(frame).shape)
        too_thin_to_describe(frame, self.name)  # a warning; the patches are invalid (the mesh has no face)
        if patches is None:  # of the size the network takes (the checkpoint's n_rings x n_angles)
            if mesh is not None:
                check_depth_config(getattr(mesh, "config", None), self.depth_config, frame, "mesh")
            patches = polar_patches(frame, kps, radius=self.radius, n_angles=self.config.n_angles,
                                    n_rings=self.config.n_rings, depth_config=self.depth_config, mesh=mesh,
                                    blur_px=self.blur_px)
        else:
            check_patches(patches, kps.xy, self.radius, frame, self.blur_px, self.depth_config)
        return Features(patches.keypoints, self.describe(patches.values, patches.valid), patches.valid,
                        angles=kps.angles, sizes=kps.sizes, scores=kps.scores, method=self.name.partition("=")[0])
