"""geofeat: geodesic-aware local features (GeoBit, GeoPatch) on RGB-D images."""

from .depth import DepthConfig, depth_noise, depth_profile
from .descriptors import Descriptor, GeoBit, check_descriptor_name, make_descriptor
from .features import Features, Matches, load_features, load_matches, save_features, save_matches
from .frame import RGBDFrame
from .geodesic.heat import HeatGeodesics, heat_polar_patches
from .geodesic.mesh import GridMesh, build_mesh
from .geodesic.polar import PolarPatches, polar_patches
from .io import read_frame, read_sequence, read_demo_frame, Sequence, write_frame, write_intrinsics
from .keypoints import Keypoints, as_keypoints, detect
from .matching import match
from .pipeline import extract
from .sim import simulate_sequence

__version__ = "0.1.0"


def __getattr__(name: str):
    """`geofeat.GeoPatch` is imported on first use, so that `import geofeat` does not import torch."""
    if name == "GeoPatch":
        from .descriptors.geopatch import GeoPatch

        return GeoPatch
    raise AttributeError(f"module 'geofeat' has no attribute {name!r}")


__all__ = [
    "DepthConfig",
    "Descriptor",
    "Features",
    "GeoBit",
    "GeoPatch",
    "as_keypoints",
    "check_descriptor_name",
    "depth_noise",
    "depth_profile",
    "Keypoints",
    "Matches",
    "detect",
    "extract",
    "load_features",
    "load_matches",
    "make_descriptor",
    "match",
    "save_features",
    "save_matches",
    "simulate_sequence",
    "GridMesh",
    "HeatGeodesics",
    "PolarPatches",
    "RGBDFrame",
    "Sequence",
    "build_mesh",
    "heat_polar_patches",
    "polar_patches",
    "read_demo_frame",
    "read_frame",
    "read_sequence",
    "write_frame",
    "write_intrinsics",
]
