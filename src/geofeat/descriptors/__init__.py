"""Local descriptors: GeoBit (and GeoPatch) on geodesic polar patches, and OpenCV baselines.

Every descriptor has `compute(frame, keypoints) -> Features`; `make_descriptor(name)` builds one
by name for the command line and the benchmark.
"""

from __future__ import annotations

from .baselines import BASELINES, OpenCVDescriptor
from .geobit import GeoBit, generate_pattern, load_pattern

GEODESIC_DESCRIPTORS = ("geobit", "geopatch")
#: The paper's other baselines (brand.py, dali.py, imagenets.py); "-sim": trained on our simulator.
PAPER_BASELINES = ("brand", "dali", "tfeat-sim", "logpolar-sim")


def available_descriptors() -> tuple[str, ...]:
    """Names accepted by `make_descriptor`."""
    return GEODESIC_DESCRIPTORS + BASELINES + PAPER_BASELINES


def make_descriptor(name: str, radius: float | None = None, depth_config=None):
    """A descriptor by name ("geobit", "geopatch", "orb", "brisk", "freak", "daisy", "sift", "brand",
    "dali", "tfeat-sim", "logpolar-sim").

    "geopatch=PATH" (or "tfeat-sim=PATH", "logpolar-sim=PATH") uses the GeoPatch weights at PATH instead of the shipped ones.
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
    if key == "brand":
        from .brand import BRAND

        return BRAND()
    if key == "dali":
        from .dali import DaLI

        return DaLI()
    if key.split("=", 1)[0] in ("tfeat-sim", "logpolar-sim"):  # "tfeat-sim=PATH": other weights
        from .imagenets import ImagePatchDescriptor  # imports torch: only when asked for

        return ImagePatchDescriptor(key.split("-", 1)[0], weights=name.split("=", 1)[1] if "=" in name else None)
    raise ValueError(f"descriptor: unknown name {name!r}; expected one of {', '.join(available_descriptors())}")


__all__ = [
    "BASELINES", "PAPER_BASELINES", "GeoBit", "OpenCVDescriptor", "available_descriptors", "generate_pattern", "load_pattern",
    "make_descriptor",
]
