"""Local descriptors: GeoBit and GeoPatch on geodesic polar patches, and OpenCV baselines.

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


def available_descriptors() -> tuple[str, ...]:
    """Names accepted by `make_descriptor` ("geopatch=PATH" too, for weights made by `geofeat train`)."""
    return GEODESIC_DESCRIPTORS + BASELINES


def check_descriptor_name(name: str) -> str:
    """The normalised descriptor name, or ValueError for an unknown name or a missing weights file.
    Builds nothing."""
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"descriptor: expected a name from {', '.join(available_descriptors())}, got {name!r}")
    key = name.strip()
    if key.lower().startswith("geopatch="):
        path = key.split("=", 1)[1]
        if not Path(path).is_file():
            raise ValueError(f"descriptor: {key!r}: no GeoPatch weights file at {path!r}")
        return "geopatch=" + path
    if key.lower() not in available_descriptors():
        raise ValueError(f"descriptor: unknown name {name!r}; expected one of {', '.join(available_descriptors())}"
                         " or geopatch=WEIGHTS.pt")
    return key.lower()


def make_descriptor(name: str, radius: float | None = None, depth_config=None) -> Descriptor:
    """A descriptor by name ("geobit", "geopatch", "orb", "brisk", "freak", "daisy", "sift").

    "geopatch=PATH" uses the GeoPatch weights at PATH instead of the shipped ones.
    `radius` (metres) and `depth_config` (a DepthConfig or a profile name) apply to the geodesic
    descriptors only."""
    key = check_descriptor_name(name)
    kwargs = {}
    if radius is not None:
        kwargs["radius"] = radius
    if depth_config is not None:
        kwargs["depth_config"] = depth_config
    if key == "geobit":
        return GeoBit(**kwargs)
    if key == "geopatch" or key.startswith("geopatch="):
        from .geopatch import GeoPatch  # imports torch: only when asked for

        if "=" in key:
            kwargs["weights"] = key.split("=", 1)[1]
        return GeoPatch(**kwargs)
    return OpenCVDescriptor(key)


__all__ = [
    "BASELINES", "Descriptor", "GeoBit", "OpenCVDescriptor", "available_descriptors", "check_descriptor_name",
    "generate_pattern", "load_pattern", "make_descriptor",
]
