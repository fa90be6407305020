"""Local descriptors: GeoBit (and GeoPatch) on geodesic polar patches, and OpenCV baselines.

Every descriptor has `compute(frame, keypoints) -> Features`; `make_descriptor(name)` builds one
by name for the command line and the benchmark.
"""

from __future__ import annotations

from .baselines import BASELINES, OpenCVDescriptor
from .geobit import GeoBit, generate_pattern, load_pattern

GEODESIC_DESCRIPTORS = ("geobit", "geopatch")


def available_descriptors() -> tuple[str, ...]:
    """Names accepted by `make_descriptor`."""
    return GEODESIC_DESCRIPTORS + BASELINES


def make_descriptor(name: str, radius: float | None = None, depth_config=None):
    """A descriptor by name ("geobit", "geopatch", "orb", "brisk", "freak", "daisy", "sift").

    "geopatch=PATH" uses the GeoPatch weights at PATH instead of the shipped ones.
    `radius` (metres) and `depth_config` apply to the geodesic descriptors only."""
    key = name.strip().lower()
    if key == "geobit":
        kwargs = {}
        if radius is not None:
            kwargs["radius"] = radius
        if depth_config is not None:
            kwargs["depth_config"] = depth_config
        return GeoBit(**kwargs)
    if key == "geopatch" or key.startswith("geopatch="):
        from .geopatch import GeoPatch  # imports torch: only when asked for

        kwargs = {"weights": name.split("=", 1)[1]} if "=" in name else {}
        if radius is not None:
            kwargs["radius"] = radius
        if depth_config is not None:
            kwargs["depth_config"] = depth_config
        return GeoPatch(**kwargs)
    if key in BASELINES:
        return OpenCVDescriptor(key)
    raise ValueError(f"descriptor: unknown name {name!r}; expected one of {', '.join(available_descriptors())}")


__all__ = [
    "BASELINES", "GeoBit", "OpenCVDescriptor", "available_descriptors", "generate_pattern", "load_pattern",
    "make_descriptor",
]
