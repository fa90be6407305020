"""Local descriptors: GeoBit and GeoPatch on geodesic polar patches, the OpenCV baselines, and the
paper's other baselines (BRAND, DaLI, TFeat- and Log-Polar-style nets trained on our simulator).

Every descriptor follows `Descriptor` (descriptors/base.py): `name`, `binary`, `metric`,
`geodesic`, `compute(frame, keypoints) -> Features`. Options follow one pattern (`settings.py`): each
class has a frozen `Settings` dataclass, and its constructor merges a settings object with keyword
arguments (`GeoBit(radius=0.05)`). `make_descriptor(name)` builds one by name for
the command line and the benchmark; `check_descriptor_name(name)` validates a name without
building anything (no weights are loaded).
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path
from typing import Any

from ..inputs import check_weights_path
from .base import Descriptor
from .baselines import BASELINES, OpenCVDescriptor
from .geobit import GeoBit, GeoBitSettings, generate_pattern, load_pattern
from .settings import PatchSettings, takes_patch_settings

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
        check_weights_path(path, f"descriptor: {key!r}", base)  # as GeoPatch(weights="")
        if not Path(path).is_file():
            raise ValueError(f"descriptor: {key!r}: no weights file at {path!r}")
        return f"{base}={path}"
    if key.lower() not in available_descriptors():
        raise ValueError(f"descriptor: unknown name {name!r}; expected one of {', '.join(available_descriptors())}"
                         " or geopatch=WEIGHTS.pt")
    return key.lower()


def refuse_repeated(names: tuple[str, ...]) -> None:
    """ValueError when a (checked) descriptor name is given twice ("orb,ORB"): each command would
    compute it twice and write its rows or results twice."""
    twice = sorted({d for d in names if names.count(d) > 1})
    if twice:
        raise ValueError(f"descriptors: {', '.join(map(repr, twice))} is named twice; name each descriptor once")


def check_descriptor_names(names) -> tuple[str, ...]:
    """`check_descriptor_name` of each of `names` (empty entries dropped), as a tuple; ValueError for
    an unknown one or for none at all. Builds nothing, so a bad name fails before any work."""
    if isinstance(names, str):  # iterating it would check its letters: "unknown name 'g'"
        raise ValueError(f"descriptors: expected a list of names such as [{names!r}], got the string {names!r}")
    checked = tuple(check_descriptor_name(d) for d in names if not isinstance(d, str) or d.strip())
    if not checked:
        raise ValueError("descriptors: expected at least one descriptor name")
    refuse_repeated(checked)
    return checked


#: Descriptor classes by name: (module, class); imported when asked for (GeoPatch and the image-patch
#: nets import torch).
_CLASSES = {"geobit": (".geobit", "GeoBit"), "geopatch": (".geopatch", "GeoPatch"), "brand": (".brand", "BRAND"),
            "dali": (".dali", "DaLI"), "tfeat-sim": (".image_patch_nets", "ImagePatchDescriptor"),
            "logpolar-sim": (".image_patch_nets", "ImagePatchDescriptor")}


def _descriptor_class(base: str) -> tuple[type, tuple[str, ...]]:
    """The class of descriptor `base` and the positional arguments naming the variant it builds (the
    OpenCV baseline's name, the image-patch net's architecture)."""
    if base in BASELINES:
        return OpenCVDescriptor, (base,)
    module, name = _CLASSES[base]
    cls = getattr(import_module(module, __name__), name)
    return cls, ((base.split("-", 1)[0],) if base.endswith("-sim") else ())


def make_descriptor(name: str, radius: float | None = None, depth_config=None, **options: Any) -> Descriptor:
    """A descriptor by name: "geobit", "geopatch", "orb", "brisk", "freak", "daisy", "sift",
    "brand", "dali", "tfeat-sim", "logpolar-sim".

    "geopatch=PATH" (or "tfeat-sim=PATH", "logpolar-sim=PATH") uses the weights at PATH instead of
    the shipped ones. `radius` (metres) and `depth_config` (a DepthConfig or a profile name) go, by
    those names, to every descriptor whose settings hold the polar patch settings
    (`settings.PatchSettings`: GeoBit, GeoPatch); the others have none. `options` are further
    settings of the descriptor (e.g. backend="torch" for GeoPatch), passed as keyword arguments."""
    key = check_descriptor_name(name)
    base, _, weights = key.partition("=")
    cls, variant = _descriptor_class(base)
    if weights:
        if options.get("weights") is not None:  # was replaced by the name's path without a word
            raise ValueError(f"descriptor: {name!r} names its weights, and weights={options['weights']!r} was "
                             "given too; give them once")
        options["weights"] = weights
    if takes_patch_settings(cls):
        patch = {k: v for k, v in (("radius", radius), ("depth_config", depth_config)) if v is not None}
        options = {**patch, **options}
    return cls(*variant, **options)


__all__ = [
    "BASELINES", "Descriptor", "GeoBit", "GeoBitSettings", "OpenCVDescriptor", "PAPER_BASELINES", "PatchSettings",
    "available_descriptors",
    "check_descriptor_name", "generate_pattern", "load_pattern", "make_descriptor",
]
