"""Several descriptors on one frame sharing one mesh and one set of polar patches (the benchmark,
tracking and retrieval describe keypoints with it), GeoPatch optionally on the GPU path."""

from __future__ import annotations

import time

from ..depth import PROFILES
from ..frame import RGBDFrame
from ..geodesic.mesh import build_mesh
from ..geodesic.polar import polar_patches
from ..gpu import gpu_computes, wants_gpu
from ..keypoints import Keypoints
from . import make_descriptor

__all__ = ["Describer"]


class Describer:
    """Describes keypoints of a frame with every descriptor; geodesic descriptors (`Descriptor.geodesic`)
    share one mesh and one set of polar patches, built with the given depth profile.

    `device`: None or "cpu" (default): every descriptor on the CPU. "cuda" / "cuda:N": the GeoPatch
    descriptors with torch weights (`geofeat.gpu.gpu_computes`) on the GPU path (torch backend on
    that device; mesh, walk, sampling and CNN there, `GeoPatch.compute_cuda`), the others on the CPU;
    `match_device` says where to match each one's features."""

    def __init__(self, names: tuple[str, ...], radius: float, profile: str = "kinect", device: str | None = None) -> None:
        """`names`: descriptor names (`make_descriptor`'s); `radius`: geodesic radius, metres; `profile`:
        a depth profile of `depth.PROFILES` ("kinect", "quantised", "clean"; "auto" is chosen per
        sequence by the caller, `depth.sequence_depth_profile`). ValueError naming the argument for a
        single string as `names` (its letters were taken as names: "unknown name 'g'") or another profile."""
        if isinstance(names, str):
            raise ValueError(f"names: expected a list of descriptor names such as [{names!r}], got the string {names!r}")
        if profile not in PROFILES:  # a bare KeyError before, "auto" included
            known = ", ".join(PROFILES)
            raise ValueError(f"profile: expected one of {known} (a Describer describes with one profile; pick 'auto' "
                             f"per sequence with geofeat.depth.sequence_depth_profile), got {profile!r}")
        self.radius = radius
        self.depth_config = PROFILES[profile]
        self.device = str(device) if wants_gpu(device) else None
        #: the descriptors described on the GPU path (none without a CUDA `device`)
        self.on_gpu = frozenset(n for n in names if self.device is not None and gpu_computes(n))
        self.descriptors = {n: make_descriptor(n, radius=radius, depth_config=self.depth_config,
                                               **({"device": self.device, "backend": "torch"} if n in self.on_gpu else {}))
                            for n in names}

    def match_device(self, name: str) -> str | None:
        """The `device` of `geofeat.match` for the features of descriptor `name`: this Describer's
        GPU for a descriptor it describes there, None (the CPU) for the others."""
        return self.device if name in self.on_gpu else None

    def __call__(self, frame: RGBDFrame, kps: Keypoints) -> dict[str, tuple]:
        """{name: (Features, seconds)}; the seconds of a geodesic descriptor include the polar patches
        (on the CPU) or its own mesh, walk and sampling (on the GPU path, the features copied back)."""
        out = {}
        patches, t_patches = None, 0.0
        if any(d.geodesic and n not in self.on_gpu for n, d in self.descriptors.items()):
            t = time.perf_counter()
            patches = polar_patches(frame, kps, radius=self.radius, mesh=build_mesh(frame, self.depth_config))
            t_patches = time.perf_counter() - t
        for name, d in self.descriptors.items():
            t = time.perf_counter()
            if name in self.on_gpu:
                from ..gpu import build_mesh_cuda

                # its mesh built for each call, as the CPU's above (`compute_cuda` would reuse one cached on the frame)
                mesh = build_mesh_cuda(frame, self.depth_config, device=self.device)
                out[name] = (d.compute_cuda(frame, kps, mesh=mesh).to_host(), time.perf_counter() - t)
                continue
            f = d.compute(frame, kps, patches=patches) if d.geodesic else d.compute(frame, kps)
            out[name] = (f, time.perf_counter() - t + (t_patches if d.geodesic else 0.0))
        return out
