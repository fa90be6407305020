"""Image-patch networks trained on our simulated data: `tfeat-sim` and `logpolar-sim`.

- **TFeat** (Balntas, Riba, Ponsa & Mikolajczyk, "Learning local feature descriptors with triplets
  and shallow convolutional neural networks", BMVC 2016): a 32x32 image patch oriented and scaled
  by the SIFT keypoint (support radius `TFEAT_RADIUS_FACTOR` x SIFT's diameter) -> conv 7x7, 32 |
  tanh | max-pool 2 | conv 6x6, 64 | tanh | linear 4096 -> 128 | tanh, as in the paper.
- **Log-Polar** (Ebel, Mishchuk, Yi, Fua & Trulls, "Beyond Cartesian representations for local
  descriptors", ICCV 2019): a 32x32 log-polar patch (rows: 32 log-spaced radii, columns: 32 angles
  from the keypoint's orientation) over a support twice TFeat's, described by a HardNet-style
  network (3x3 convolutions, BN, ReLU, two stride-2 stages, an 8x8 convolution to 128, L2 norm).

Where ours departs, and why:

- Both are trained with geofeat's own loop (`geofeat.train.loop.train`: triplet margin loss with
  anchor swap / hardest-in-batch negatives, SGD) on the **same simulated sequences as GeoPatch**
  (`geofeat train --net tfeat|logpolar`), not on the published Liberty / PhotoTourism weights, which
  cannot be fetched at run time. Geodesic patches versus image patches, everything else equal; the
  `-sim` suffix says so in every table.
- TFeat's output is L2-normalised (the shared loop's margin assumes unit descriptors).
- Our Log-Polar net is HardNet at half width (16/16/32/32/64/64 channels instead of
  32/32/64/64/128/128) so that it trains in ~20 min on a shared CPU and describes 2048 keypoints in
  about a second; the convolutions pad the angle axis circularly (the log-polar patch is periodic
  in angle) and the radius axis with zeros. Both nets z-score each patch first (HardNet does too).
- Patches are oriented by the keypoint's angle and scaled by its size; bare (N, 2) positions get
  angle 0 and size 8 px (`baselines.DEFAULT_SIZE_PX`, as for the OpenCV baselines).

Weights ship in geofeat/data (`tfeat_sim.pt`, `logpolar_sim.pt`); the training command and its
figures are in BENCHMARKS.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..features import Features
from ..frame import RGBDFrame, too_thin_to_describe
from ..keypoints import Keypoints, as_keypoints
from .patches import cartesian_grid, keypoint_arrays, logpolar_grid, sample_patches
from .settings import merge_settings
from ..inputs import check_weights_path, check_whole

#: Support radius of a TFeat patch = this x the keypoint diameter (pixels): a patch side of 6x
#: SIFT's size, the factor at which BRISK/FREAK plateau under scale (BENCHMARKS.md).
TFEAT_RADIUS_FACTOR = 3.0
#: Log-Polar's support radius = this x the keypoint diameter (twice TFeat's: "a large support").
LOGPOLAR_RADIUS_FACTOR = 6.0
#: Innermost log-polar circle, as a fraction of the support radius.
LOGPOLAR_MIN_RADIUS = 1.0 / 32.0
#: Patch side (samples).
PATCH_SIZE = 32
#: Shipped weights per architecture (files in geofeat/data).
WEIGHTS = {"tfeat": "tfeat_sim.pt", "logpolar": "logpolar_sim.pt"}
ARCHS = tuple(WEIGHTS)


@dataclass(frozen=True)
class ImageNetConfig:
    """arch: "tfeat" or "logpolar"; dim: descriptor size; width: first-layer channels."""

    arch: str = "tfeat"
    dim: int = 128
    width: int = 32

    def __post_init__(self) -> None:
        if self.arch not in ARCHS:
            raise ValueError(f"arch: expected one of {ARCHS}, got {self.arch!r}")


def default_config(arch: str) -> ImageNetConfig:
    return ImageNetConfig(arch=arch, width=32 if arch == "tfeat" else 16)


def _zscore(x: torch.Tensor) -> torch.Tensor:
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    return (x - mean) / (x.std(dim=(1, 2, 3), keepdim=True) + 1e-6)


class PolarConv(nn.Module):
    """3x3 conv on (B, C, radii, angles): circular padding on angles, zeros on radii."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 3, stride=stride, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.pad(F.pad(x, (1, 1, 0, 0), mode="circular"), (0, 0, 1, 1))
        return self.conv(x)


class ImagePatchNet(nn.Module):
    """(B, 1, 32, 32) patches (any intensity scale) -> (B, dim) unit-length descriptors."""

    def __init__(self, config: ImageNetConfig = ImageNetConfig()) -> None:
        super().__init__()
        self.config = config
        w = config.width
        if config.arch == "tfeat":
            self.features = nn.Sequential(nn.Conv2d(1, w, 7), nn.Tanh(), nn.MaxPool2d(2),
                                          nn.Conv2d(w, 2 * w, 6), nn.Tanh())
            self.head = nn.Sequential(nn.Flatten(), nn.Linear(2 * w * 8 * 8, config.dim), nn.Tanh())
        else:
            chans = [(1, w, 1), (w, w, 1), (w, 2 * w, 2), (2 * w, 2 * w, 1), (2 * w, 4 * w, 2), (4 * w, 4 * w, 1)]
            layers: list[nn.Module] = []
            for cin, cout, stride in chans:
                layers += [PolarConv(cin, cout, stride), nn.BatchNorm2d(cout, affine=False), nn.ReLU(inplace=True)]
            self.features = nn.Sequential(*layers)
            self.head = nn.Sequential(nn.Dropout(0.3), nn.Conv2d(4 * w, config.dim, 8, bias=False),
                                      nn.BatchNorm2d(config.dim, affine=False), nn.Flatten())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.head(self.features(_zscore(x))), dim=1)


def image_patches(image: np.ndarray, keypoints, arch: str) -> np.ndarray:
    """(N, 32, 32) float32 input patches of `arch` for `keypoints` on a (H, W) gray image in [0, 1]."""
    xy, angles, sizes = keypoint_arrays(keypoints, f"{arch}-sim")
    if arch == "tfeat":
        return sample_patches(image, xy, angles, TFEAT_RADIUS_FACTOR * sizes, cartesian_grid(PATCH_SIZE))
    if arch == "logpolar":
        grid = logpolar_grid(PATCH_SIZE, PATCH_SIZE, LOGPOLAR_MIN_RADIUS)
        return sample_patches(image, xy, angles, LOGPOLAR_RADIUS_FACTOR * sizes, grid)
    raise ValueError(f"arch: expected one of {ARCHS}, got {arch!r}")


def default_weights_path(arch: str) -> Path:
    return Path(str(resources.files("geofeat") / "data" / WEIGHTS[arch]))


def load_image_net(path: str | Path, arch: str | None = None) -> ImagePatchNet:
    """An ImagePatchNet (eval mode) from a checkpoint written by the training loop. Offline only.
    `arch`: the architecture the checkpoint must hold ("tfeat" or "logpolar"; None: any)."""
    from .geopatch_net import load_checkpoint

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"weights: no image-patch network checkpoint at {path}")
    what = f"{arch}-sim" if arch else "tfeat-sim or logpolar-sim"
    net, _ = load_checkpoint(path, lambda config: ImagePatchNet(ImageNetConfig(**config)), what)
    if arch is not None and net.config.arch != arch:
        raise ValueError(f"weights: {path} holds a {net.config.arch}-sim network, not {arch}-sim")
    return net.eval()


@dataclass(frozen=True)
class ImagePatchSettings:
    """Options of `ImagePatchDescriptor`. weights: checkpoint path; None = the shipped weights;
    "random" = an untrained net (seeded; the reference the trained weights must beat). batch_size:
    patches per forward pass."""

    weights: str | Path | None = None
    batch_size: int = 256

    def __post_init__(self) -> None:
        check_weights_path(self.weights)  # "" said "no image-patch network checkpoint at ."


class ImagePatchDescriptor:
    """`tfeat-sim` / `logpolar-sim`: image patches -> ImagePatchNet -> (N, 128) float32 unit vectors.

    `arch` ("tfeat" or "logpolar") says which descriptor; options: `ImagePatchSettings`, given and
    merged as `geofeat.descriptors.settings` says.
    """

    Settings = ImagePatchSettings

    def __init__(self, arch: str, settings: ImagePatchSettings | Mapping[str, Any] | None = None,
                 **kwargs: Any) -> None:
        self.settings = s = merge_settings(ImagePatchSettings, settings, kwargs)
        weights = s.weights
        if arch not in ARCHS:
            raise ValueError(f"arch: expected one of {ARCHS}, got {arch!r}")
        self.arch = arch
        self.name = f"{arch}-sim"
        self.binary, self.metric, self.geodesic = False, "l2", False
        if weights == "random":
            with torch.random.fork_rng():  # seeded, without touching the caller's torch RNG
                torch.manual_seed(0)
                self.net = ImagePatchNet(default_config(arch)).eval()
        else:
            self.net = load_image_net(default_weights_path(arch) if weights is None else weights, arch)
        check_whole(s.batch_size, "batch_size", 1)
        self.batch_size = int(s.batch_size)

    def __repr__(self) -> str:
        return f"ImagePatchDescriptor({self.name}, config={self.net.config})"

    @torch.inference_mode()
    def describe(self, patches: np.ndarray) -> np.ndarray:
        """(N, 32, 32) patches -> (N, dim) float32 descriptors."""
        patches = np.asarray(patches)
        if patches.ndim != 3 or patches.shape[1:] != (PATCH_SIZE, PATCH_SIZE):
            # logpolar-sim's convolutional head turned (N, 64, 64) patches into (N, 10368) "descriptors"
            # without a word; tfeat-sim failed inside torch ("mat1 and mat2 shapes cannot be multiplied")
            raise ValueError(f"patches: expected shape (N, {PATCH_SIZE}, {PATCH_SIZE}), got {patches.shape}")
        x = torch.from_numpy(np.ascontiguousarray(patches, np.float32)).unsqueeze(1)
        out = [self.net(x[i:i + self.batch_size]) for i in range(0, len(x), self.batch_size)]
        return torch.cat(out).numpy() if out else np.zeros((0, self.net.config.dim), np.float32)

    def compute(self, frame: RGBDFrame, keypoints) -> Features:
        """Features of `keypoints` (Keypoints, cv2.KeyPoint list, or (N, 2) pixels: angle 0, size 8 px);
        all invalid, with a warning, on a frame 1 pixel high or wide (`too_thin_to_describe`)."""
        if not hasattr(frame, "image"):
            raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
        kps = as_keypoints(keypoints, frame.image.shape[:2])
        xy, angles, sizes = keypoint_arrays(kps, self.name, frame.image.shape[:2])
        if too_thin_to_describe(frame, self.name):
            return Features(xy, np.zeros((len(xy), self.net.config.dim), np.float32), np.zeros(len(xy), bool),
                            angles=angles, sizes=kps.sizes, scores=kps.scores, method=self.name)
        patches = image_patches(frame.image, Keypoints(xy, angles, sizes, np.zeros(len(xy))), self.arch)
        return Features(xy, self.describe(patches), np.ones(len(xy), bool), angles=angles, sizes=kps.sizes,
                        scores=kps.scores, method=self.name)

