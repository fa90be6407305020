"""Several descriptors on one frame sharing one mesh and one set of polar patches (the benchmark,
tracking and retrieval describe keypoints with it)."""

from __future__ import annotations

import time

from ..depth import PROFILES
from ..frame import RGBDFrame
from ..geodesic.mesh import build_mesh
from ..geodesic.polar import polar_patches
from ..keypoints import Keypoints
from . import make_descriptor

__all__ = ["Describer"]


class Describer:
    """Describes keypoints of a frame with every descriptor; geodesic descriptors (`Descriptor.geodesic`)
    share one mesh and one set of polar patches, built with the given depth profile."""

    def __init__(self, names: tuple[str, ...], radius: float, profile: str = "kinect") -> None:
        self.radius = radius
        self.depth_config = PROFILES[profile]
        self.descriptors = {n: make_descriptor(n, radius=radius, depth_config=self.depth_config) for n in names}

    def __call__(self, frame: RGBDFrame, kps: Keypoints) -> dict[str, tuple]:
        """{name: (Features, seconds)}; the seconds of a geodesic descriptor include the polar patches."""
        out = {}
        patches, t_patches = None, 0.0
        if any(d.geodesic for d in self.descriptors.values()):
            t = time.perf_counter()
            patches = polar_patches(frame, kps, radius=self.radius, mesh=build_mesh(frame, self.depth_config))
            t_patches = time.perf_counter() - t
        for name, d in self.descriptors.items():
            t = time.perf_counter()
            f = d.compute(frame, kps, patches=patches) if d.geodesic else d.compute(frame, kps)
            out[name] = (f, time.perf_counter() - t + (t_patches if d.geodesic else 0.0))
        return out
