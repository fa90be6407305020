"""One pattern for descriptor options: a frozen dataclass of settings per descriptor (the class's
`Settings`), merged with keyword arguments (LightGlue's `default_conf`). Every descriptor's
constructor takes `(settings=None, **kwargs)`: `settings` is a `Settings` instance or a dict of its
fields (None: the defaults), and keyword arguments, any of its fields, override it (`merge_settings`).
`GeoBit(radius=0.05)`, `GeoBit({"radius": 0.05})` and `GeoBit(GeoBitSettings(radius=0.05))` build the
same descriptor; the merged settings are the descriptor's `settings` attribute.

The descriptors built on geodesic polar patches (GeoBit, GeoPatch) share `PatchSettings` (radius,
depth preprocessing, sampling blur): `make_descriptor` passes the radius and depth settings to every
descriptor whose settings hold them, by the same keyword names.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, TypeVar

from ..constants import DEFAULT_RADIUS_M, SAMPLING_BLUR_PX
from ..depth import DepthConfig, check_profile
from ..inputs import check_radius

__all__ = ["PatchSettings", "merge_settings", "takes_patch_settings"]

S = TypeVar("S")


@dataclass(frozen=True)
class PatchSettings:
    """Polar patch settings of the geodesic descriptors (`geofeat.polar_patches`).

    Attributes:
        radius: geodesic radius of the patch, metres.
        depth_config: depth preprocessing, a `DepthConfig` or a profile name ("kinect",
            "quantised", "clean", "auto": chosen per frame from the measured depth noise).
        blur_px: Gaussian blur of the image before sampling, pixels.
    """

    radius: float = DEFAULT_RADIUS_M
    depth_config: DepthConfig | str = "auto"
    blur_px: float = SAMPLING_BLUR_PX

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", check_radius(self.radius, "radius"))  # "0.05" was read as a number
        if not isinstance(self.depth_config, DepthConfig):
            object.__setattr__(self, "depth_config", check_profile(self.depth_config, "depth_config"))


def merge_settings(cls: type[S], settings: S | Mapping[str, Any] | None, overrides: Mapping[str, Any]) -> S:
    """The settings of a descriptor: `cls`'s defaults, replaced by `settings` (a `cls` instance or a
    dict of its fields), then by the keyword arguments `overrides`.

    Raises:
        TypeError: `settings` of another kind, or a name that is not a field of `cls`.
    """
    names = [f.name for f in fields(cls)]
    if settings is None:
        base: dict[str, Any] = {}
    elif isinstance(settings, cls):
        base = {n: getattr(settings, n) for n in names}
    elif isinstance(settings, Mapping):
        base = dict(settings)
    else:
        raise TypeError(f"settings: expected a {cls.__name__}, a dict of its fields or None, got "
                        f"{type(settings).__name__} (pass options by name, e.g. weights=...)")
    merged = {**base, **overrides}
    unknown = sorted(set(merged) - set(names))
    if unknown:
        raise TypeError(f"{cls.__name__}: unknown option(s) {', '.join(unknown)}; expected {', '.join(names)}")
    return cls(**merged)


def takes_patch_settings(descriptor_class: type) -> bool:
    """True when `descriptor_class.Settings` holds the polar patch settings (radius, depth_config)."""
    settings = getattr(descriptor_class, "Settings", None)
    return isinstance(settings, type) and issubclass(settings, PatchSettings)
