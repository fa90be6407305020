"""geofeat: geodesic-aware local features (GeoBit, GeoPatch) on RGB-D images."""

from .depth import DepthConfig
from .descriptors import GeoBit, make_descriptor
from .features import Features, Matches, load_features, load_matches, save_features, save_matches
from .frame import RGBDFrame
from .geodesic.heat import HeatGeodesics, heat_polar_patches
from .geodesic.mesh import GridMesh, build_mesh
from .geodesic.polar import PolarPatches, polar_patches
from .io import read_frame, read_sequence, read_demo_frame, Sequence
from .keypoints import Keypoints, detect
from .matching import match
from .sim import simulate_sequence

__version__ = "0.1.0"

__all__ = [
    "DepthConfig",
    "Features",
    "GeoBit",
    "Keypoints",
    "Matches",
    "detect",
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
]
