"""The Descriptor protocol: what the benchmark, the applications and the command line need of a
descriptor, so that none of them dispatches on name strings.

A descriptor is any object with

- ``name``: its registry name (``make_descriptor(name)`` builds it again),
- ``binary``: True for bit strings compared by Hamming distance, False for float vectors (L2),
- ``metric``: the distance `geofeat.match` uses for it: ``"l2"``, ``"hamming"`` or ``"hamming-rot"``
  (minimum Hamming distance over rotated copies, GeoBit),
- ``geodesic``: True when it is computed on geodesic polar patches; its ``compute`` then also takes
  ``patches=`` (a `PolarPatches` of the same keypoints) and ``mesh=``, so that several geodesic
  descriptors of one frame share the mesh and the patches,
- ``compute(frame, keypoints) -> Features``, keypoints in any form `geofeat.keypoints.as_keypoints`
  accepts.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ..features import Features
from ..frame import RGBDFrame

__all__ = ["Descriptor"]


@runtime_checkable
class Descriptor(Protocol):
    """Structural type of every geofeat descriptor (see the module docstring)."""

    name: str
    binary: bool
    metric: str
    geodesic: bool

    def compute(self, frame: RGBDFrame, keypoints) -> Features:
        """Describe `keypoints` on `frame`; one row per keypoint, `valid` False where impossible."""
        ...
