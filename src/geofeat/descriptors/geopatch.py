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
speed-first choice; the shipped weights (v8) use the paper's 32/64/128 (at equal training they
scored 0.227 against 0.204 on the `hard` test sequences) and cost 1.6x the half-width net (0.22 s for 2048 patches on 2
CPU threads); the checkpoint carries its own shape. See BENCHMARKS.md. `angle_pool=False` flattens
instead (the ablation without rotation invariance).

Trained weights ship in `geofeat/data/geopatch.pt` (trained by `geofeat train` on simulated
sequences; see the training notes in BENCHMARKS.md) and load offline.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..constants import DEFAULT_RADIUS_M, N_ANGLES, N_RINGS, SAMPLING_BLUR_PX
from ..depth import DepthConfig, check_profile
from ..features import Features
from ..frame import RGBDFrame
from ..keypoints import as_keypoints
from ..geodesic.mesh import GridMesh
from ..geodesic.polar import PolarPatches, polar_patches

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


class CircularConv(nn.Module):
    """Conv2d on (B, C, rings, angles) with circular padding on the angle axis only."""

    def __init__(self, cin: int, cout: int, k: int) -> None:
        super().__init__()
        self.pad = k // 2
        self.conv = nn.Conv2d(cin, cout, k)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(F.pad(x, (self.pad, self.pad, 0, 0), mode="circular"))


class MaxPool2x2(nn.Module):
    """2x2 max pooling, stride 2 (even sizes), as the maximum of four strided views. On CPU this is
    faster than nn.MaxPool2d, which here falls back to a kernel that also computes argmax indices."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        top = torch.maximum(x[:, :, 0::2, 0::2], x[:, :, 0::2, 1::2])
        return torch.maximum(top, torch.maximum(x[:, :, 1::2, 0::2], x[:, :, 1::2, 1::2]))


class GeoPatchNet(nn.Module):
    """(B, 1, R, A) polar patches (any intensity scale) -> (B, dim) unit-length descriptors."""

    def __init__(self, config: GeoPatchConfig = GeoPatchConfig()) -> None:
        super().__init__()
        self.config = config
        c1, c2, c3 = config.channels
        self.features = nn.Sequential(
            CircularConv(1, c1, 5), nn.BatchNorm2d(c1), nn.ReLU(inplace=True), MaxPool2x2(),
            CircularConv(c1, c2, 3), nn.BatchNorm2d(c2), nn.ReLU(inplace=True), MaxPool2x2(),
            CircularConv(c2, c3, 3), nn.BatchNorm2d(c3), nn.ReLU(inplace=True),
        )
        with torch.no_grad():
            _, c, h, w = self.features(torch.zeros(2, 1, config.n_rings, config.n_angles)).shape
        self.head = nn.Linear(c * h if config.angle_pool else c * h * w, config.dim)

    @staticmethod
    def normalise(x: torch.Tensor) -> torch.Tensor:
        """Per-patch z-score (flat patches stay 0 instead of NaN)."""
        mean = x.mean(dim=(1, 2, 3), keepdim=True)
        std = x.std(dim=(1, 2, 3), keepdim=True)
        return (x - mean) / (std + 1e-6)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.features(self.normalise(x))
        y = y.amax(dim=3) if self.config.angle_pool else y
        return F.normalize(self.head(y.flatten(1)), dim=1)


def fuse_batchnorm(net: GeoPatchNet) -> GeoPatchNet:
    """An inference copy of `net` with every BatchNorm folded into the convolution before it
    (same outputs up to float rounding, one pass less over the activations)."""
    import copy

    fused = copy.deepcopy(net).eval()
    layers = list(fused.features)
    kept = []
    for layer in layers:
        if isinstance(layer, nn.BatchNorm2d) and kept and isinstance(kept[-1], CircularConv):
            conv = kept[-1].conv
            scale = layer.weight / torch.sqrt(layer.running_var + layer.eps)
            with torch.no_grad():
                conv.weight.mul_(scale.reshape(-1, 1, 1, 1))
                conv.bias.copy_((conv.bias - layer.running_mean) * scale + layer.bias)
            continue
        kept.append(layer)
    fused.features = nn.Sequential(*kept)
    return fused


def default_weights_path() -> Path:
    return Path(str(resources.files("geofeat") / "data" / WEIGHTS_NAME))


def save_checkpoint(path: str | Path, net: GeoPatchNet, **meta) -> None:
    """Save weights + config (+ any metadata, e.g. optimiser state, epoch, training settings)."""
    torch.save({"config": asdict(net.config), "state_dict": net.state_dict(), **meta}, str(path))


def load_network(path: str | Path | None = None, device: str | torch.device | None = None) -> tuple[GeoPatchNet, dict]:
    """Load a GeoPatchNet (eval mode) from a checkpoint; None = the shipped weights. Offline only."""
    path = default_weights_path() if path is None else Path(path)
    if not path.is_file():
        raise ValueError(f"weights: no GeoPatch checkpoint at {path}")
    ckpt = torch.load(str(path), map_location="cpu", weights_only=False)
    config = dict(ckpt["config"])
    config["channels"] = tuple(config["channels"])
    net = GeoPatchNet(GeoPatchConfig(**config))
    net.load_state_dict(ckpt["state_dict"])
    net.eval()
    if device is not None:
        net.to(device)
    return net, ckpt


class GeoPatch:
    """GeoPatch descriptor extractor: polar patches -> GeoPatchNet -> (N, 128) float32 unit vectors
    (a `geofeat.descriptors.base.Descriptor`).

    Args:
        weights: checkpoint path; None = the weights shipped with geofeat.
        device: "cpu", "cuda", ... (default: CUDA when available).
        radius, depth_config, blur_px: polar patch settings (`geofeat.polar_patches`).
        batch_size: patches per forward pass on CPU (small batches keep activations in cache; on
            CUDA at least 4096 patches go in one pass).
        threads: torch CPU threads for `describe` (set for the call, then restored); None keeps
            torch's setting. On a machine shared with other busy processes 1 thread can be several
            times faster than 2 (torch's OpenMP threads wait on each other; see BENCHMARKS.md).
    """

    def __init__(self, weights: str | Path | None = None, device: str | None = None,
                 radius: float = DEFAULT_RADIUS_M, depth_config: DepthConfig | str = "auto",
                 blur_px: float = SAMPLING_BLUR_PX, batch_size: int = 128, threads: int | None = None) -> None:
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        net, self.checkpoint = load_network(weights)
        self.net = fuse_batchnorm(net).to(self.device)
        self.radius = float(radius)
        self.name = "geopatch" if weights is None else f"geopatch={weights}"
        self.binary, self.metric, self.geodesic = False, "l2", True
        self.depth_config = depth_config if isinstance(depth_config, DepthConfig) else check_profile(
            depth_config, "depth_config")
        self.blur_px = blur_px
        self.batch_size = int(batch_size)
        if threads is not None and int(threads) < 1:
            raise ValueError(f"threads: expected a positive number of CPU threads or None, got {threads}")
        self.threads = None if threads is None else int(threads)

    def __repr__(self) -> str:
        return f"GeoPatch(config={self.net.config}, device={self.device}, radius={self.radius})"

    @torch.inference_mode()
    def describe(self, patch_values: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
        """(N, R, A) polar patches -> (N, dim) float32 descriptors; rows of invalid patches are 0."""
        v = np.asarray(patch_values, dtype=np.float32)
        cfg = self.net.config
        if v.ndim != 3 or v.shape[1:] != (cfg.n_rings, cfg.n_angles):
            raise ValueError(f"patch_values: expected shape (N, {cfg.n_rings}, {cfg.n_angles}), got {v.shape}")
        n = v.shape[0]
        valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool).reshape(n)
        out = np.zeros((n, cfg.dim), np.float32)
        index = np.flatnonzero(valid)
        if len(index) == 0:
            return out
        # one transfer each way: the patches to the device, the descriptors back (on CUDA the
        # per-batch copies and synchronisations would cost more than the network)
        x = torch.from_numpy(np.ascontiguousarray(v[index])).to(self.device).unsqueeze(1)
        batch = self.batch_size if self.device.type == "cpu" else max(self.batch_size, 4096)
        before = torch.get_num_threads()
        if self.threads is not None:
            torch.set_num_threads(self.threads)
        try:
            y = torch.cat([self.net(x[start:start + batch]) for start in range(0, len(index), batch)])
        finally:
            torch.set_num_threads(before)
        out[index] = y.float().cpu().numpy()
        return out

    def compute(self, frame: RGBDFrame, keypoints, patches: PolarPatches | None = None,
                mesh: GridMesh | None = None) -> Features:
        """GeoPatch features of `keypoints` ((N, 2) pixels, cv2.KeyPoint list or `Keypoints`)."""
        kps = as_keypoints(keypoints, frame.shape)
        if patches is None:
            patches = polar_patches(frame, kps, radius=self.radius, depth_config=self.depth_config,
                                    mesh=mesh, blur_px=self.blur_px)
        elif len(patches) != len(kps):
            raise ValueError(f"patches: hold {len(patches)} keypoints, but {len(kps)} keypoints were given")
        return Features(patches.keypoints, self.describe(patches.values, patches.valid), patches.valid,
                        angles=kps.angles, sizes=kps.sizes)
