"""Local descriptors: GeoBit and GeoPatch on geodesic polar patches, the OpenCV baselines, and the
paper's other baselines (BRAND, DaLI, TFeat- and Log-Polar-style nets trained on our simulator).

Every descriptor follows `Descriptor` (descriptors/base.py): `name`, `binary`, `metric`,
`geodesic`, `compute(frame, keypoints) -> Features`. `make_descriptor(name)` builds one by name for
the command line and the benchmark; `check_descriptor_name(name)` validates a name without
building anything (no weights are loaded).
"""

from __future__ import annotations

from pathlib import Path

from .base import Descriptor
from .baselines import BASELINES, OpenCVDescriptor
from .geobit import GeoBit, generate_pattern, load_pattern

GEODESIC_DESCRIPTORS = ("geobit", "geopatch")
#: The paper's other baselines (brand.py, dali.py, image_patch_nets.py); "-sim": trained on our simulator.
PAPER_BASELINES = ("brand", "dali", "tfeat-sim", "logpolar-sim")
#: Names that take other weights as "NAME=PATH".
TRAINED = ("geopatch", "tfeat-sim", "logpolar-sim")


def available_descriptors() -> tuple[str, ...]:
    """Names accepted by `make_descriptor` ("geopatch=PATH", "tfeat-sim=PATH", "logpolar-sim=PATH"
    too, for weights made by `geofeat train`)."""
    return GEODESIC_DESCRIPTORS + BASELINES + PAPER_BASELINES


def check_descriptor_name(name: str) -> str:
    """The normalised descriptor name, or ValueError for an unknown name or a missing weights file.
    Builds nothing."""
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"descriptor: expected a name from {', '.join(available_descriptors())}, got {name!r}")
    key = name.strip()
    base = key.split("=", 1)[0].lower()
    if "=" in key and base in TRAINED:
        path = key.split("=", 1)[1]
        if not Path(path).is_file():
            raise ValueError(f"descriptor: {key!r}: no weights file at {path!r}")
        return f"{base}={path}"
    if key.lower() not in available_descriptors():
        raise ValueError(f"descriptor: unknown name {name!r}; expected one of {', '.join(available_descriptors())}"
                         " or geopatch=WEIGHTS.pt")
    return key.lower()


def make_descriptor(name: str, radius: float | None = None, depth_config=None) -> Descriptor:
    """A descriptor by name: "geobit", "geopatch", "orb", "brisk", "freak", "daisy", "sift",
    "brand", "dali", "tfeat-sim", "logpolar-sim".

    "geopatch=PATH" (or "tfeat-sim=PATH", "logpolar-sim=PATH") uses the weights at PATH instead of
    the shipped ones. `radius` (metres) and `depth_config` (a DepthConfig or a profile name) apply
    to the geodesic descriptors only."""
    key = check_descriptor_name(name)
    base, _, weights = key.partition("=")
    kwargs = {}
    if radius is not None:
        kwargs["radius"] = radius
    if depth_config is not None:
        kwargs["depth_config"] = depth_config
    if base == "geobit":
        return GeoBit(**kwargs)
    if base == "geopatch":
        from .geopatch import GeoPatch  # imports torch: only when asked for

        return GeoPatch(weights=weights or None, **kwargs)
    if base in BASELINES:
        return OpenCVDescriptor(base)
    if base == "brand":
        from .brand import BRAND

        return BRAND()
    if base == "dali":
        from .dali import DaLI

        return DaLI()
    from .image_patch_nets import ImagePatchDescriptor  # tfeat-sim, logpolar-sim; imports torch

    return ImagePatchDescriptor(base.split("-", 1)[0], weights=weights or None)


__all__ = [
    "BASELINES", "Descriptor", "GeoBit", "OpenCVDescriptor", "PAPER_BASELINES", "available_descriptors",
    "check_descriptor_name", "generate_pattern", "load_pattern", "make_descriptor",
]
