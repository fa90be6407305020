"""The GeoPatch network in torch (`GeoPatchNet`; architecture in `geofeat.descriptors.geopatch`),
its checkpoints, and batch-norm folding. Imported only by the torch backend and by training, so that
GeoPatch inference through ONNX Runtime does not import torch."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..inputs import check_weights_path
from .geopatch import GeoPatchConfig, default_weights_path


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


def save_checkpoint(path: str | Path, net: GeoPatchNet, **meta) -> None:
    """Save weights + config (+ any metadata, e.g. optimiser state, epoch, training settings)."""
    # through a file object: given a name, torch names the archive's records after the name up to its
    # last dot, and a name with only a leading one (".geofeat-partial-...-weights", the temporary file
    # of `geofeat train --out weights`) left none: "invalid file name", after the whole training
    with open(path, "wb") as fh:
        torch.save({"config": asdict(net.config), "state_dict": net.state_dict(), **meta}, fh)


def load_checkpoint(path: str | Path, build, what: str) -> tuple[nn.Module, dict]:
    """(network, checkpoint) of a checkpoint written by `geofeat train`: `build(config)` makes the
    network from the checkpoint's config, which then takes its state dict. ValueError naming the file
    when it is corrupt, not a checkpoint, or holds another network's weights (`what` names the one
    expected, e.g. "GeoPatch"). Loading draws nothing from the caller's torch random generator: the
    network's random initial weights, replaced at once by the checkpoint's, come from a copy of it
    (a host application that seeded torch gets the same random numbers after making a descriptor)."""
    ckpt = None
    try:
        ckpt = torch.load(str(path), map_location="cpu", weights_only=False)
        with torch.random.fork_rng(devices=[]):  # the network is built on the CPU
            net = build(dict(ckpt["config"]))
        net.load_state_dict(ckpt["state_dict"])
    except Exception as error:  # noqa: BLE001 - unpickling, a missing key, another architecture: all one user error
        from ..inputs import error_summary

        other = _trained_name(ckpt)  # `geofeat train --net` wrote another network's weights
        if other is not None and other not in what.lower():
            raise ValueError(f"weights: {path} holds {other} weights (geofeat train --net), not {what}; name them "
                             f"{other}=PATH") from None
        torch_file = _torch_file(ckpt, what, Path(path))  # torch read it: a zip archive, never a NumPy one
        if torch_file is not None:
            raise ValueError(f"weights: {path} {torch_file}") from None
        # an archive torch could not read at all: torch's message named an array of it ("not in a subdirectory:
        # mean.npy"); a file torch read is a torch zip, which NumPy opens too ("arrays archive/data.pkl, ...")
        archive = _numpy_archive(path) if ckpt is None else None
        if archive is not None:
            what_it_is, hint = archive
            raise ValueError(f"weights: {path} {what_it_is}, not a {what} checkpoint of `geofeat train`{hint}") \
                from None
        raise ValueError(f"weights: {path} is not a {what} checkpoint of `geofeat train` ({error_summary(error)})") \
            from None
    if not all(torch.isfinite(t).all() for t in net.state_dict().values() if t.is_floating_point()):
        raise ValueError(f"weights: {path} holds NaN or infinite weights (its training diverged); train again with "
                         "a smaller --lr")
    return net, ckpt


def _torch_file(ckpt, what: str, path: Path) -> str | None:
    """What a file `path` that torch read (`ckpt`) but that holds no `what` checkpoint is, and what to give
    instead, in words: the state `geofeat train` resumes from (OUT.ckpt), or a bare state dict (a
    network saved with `torch.save(net.state_dict(), ...)`, without the config that gives its shape);
    None for anything else. Such files are zip archives, which NumPy also opens: they were reported as
    "a NumPy .npz archive (arrays archive/data.pkl, ...)"."""
    if not isinstance(ckpt, dict):
        return None
    if {"state_dict", "optimizer", "history"} <= set(ckpt) and "config" not in ckpt:
        out = path.with_name(path.name.removesuffix(".ckpt")) if path.name.endswith(".ckpt") else "OUT"
        return (f"is the state `geofeat train --out {out}` saves after each epoch to resume from (OUT.ckpt), not "
                f"weights; the weights are {out}, written when the run ends (rerun it with --resume to finish an "
                "interrupted one)")
    if ckpt and all(isinstance(k, str) and hasattr(v, "shape") for k, v in ckpt.items()):
        return (f"holds a bare state dict (tensors {', '.join(list(ckpt)[:3])}, ...) without the network's config, "
                f"not a {what} checkpoint of `geofeat train`; save the network with "
                "geofeat.descriptors.geopatch_net.save_checkpoint(path, net), which records its shape")
    return None


def _numpy_archive(path: str | Path) -> tuple[str, str] | None:
    """(what, advice) in words for a NumPy .npz archive given for a checkpoint (GeoKey's weights, from
    `geofeat train-detector`, are one); None when the file is not such an archive."""
    from ..features import read_npz

    try:
        arrays = read_npz(path)
    except (OSError, ValueError):
        return None
    if "cue_names" in arrays:
        return ("holds GeoKey detector weights (from `geofeat train-detector`)",
                '; detector weights are given as --detector geokey=PATH (detector="geokey=PATH" in Python)')
    return f"is a NumPy .npz archive (arrays {', '.join(sorted(arrays)[:5])})", ""


def _trained_name(ckpt) -> str | None:
    """The descriptor name ("geopatch", "tfeat-sim", "logpolar-sim") of a checkpoint `geofeat train`
    wrote, from its config; None when it is not one."""
    config = ckpt.get("config") if isinstance(ckpt, dict) else None
    if not isinstance(config, dict):
        return None
    if "channels" in config:
        return "geopatch"
    return f"{config['arch']}-sim" if config.get("arch") in ("tfeat", "logpolar") else None


def load_network(path: str | Path | None = None, device: str | torch.device | None = None) -> tuple[GeoPatchNet, dict]:
    """Load a GeoPatchNet (eval mode) from a checkpoint; None = the shipped weights. Offline only."""
    path = default_weights_path() if check_weights_path(path) is None else Path(path)
    if not path.is_file():
        raise ValueError(f"weights: no GeoPatch checkpoint at {path}")

    def build(config: dict) -> GeoPatchNet:
        return GeoPatchNet(GeoPatchConfig(**dict(config, channels=tuple(config["channels"]))))

    net, ckpt = load_checkpoint(path, build, "GeoPatch")
    net.eval()
    if device is not None:
        net.to(device)
    return net, ckpt
