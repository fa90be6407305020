"""Cloth simulator: deforming RGB-D sequences with exact dense ground truth.

    from geofeat.sim import simulate_sequence, correspondences
    folder = simulate_sequence("out/seq", scenario="rotate", n_frames=30, seed=1, preset="hard", fov=90)
"""

from .cloth import Cloth, ClothConfig
from ..groundtruth.simulator import correspondences, has_ground_truth, map_points
from .render import RenderOutput, render
from .scenes import PRESETS, SCENARIOS, ClothScene, Preset, default_intrinsics
from .textures import FABRIC_KINDS, fabric_texture, jitter_colours, packaged_texture_dir, procedural_texture
from .writer import simulate_sequence

__all__ = [
    "FABRIC_KINDS",
    "PRESETS",
    "Preset",
    "SCENARIOS",
    "fabric_texture",
    "jitter_colours",
    "Cloth",
    "ClothConfig",
    "ClothScene",
    "RenderOutput",
    "correspondences",
    "default_intrinsics",
    "has_ground_truth",
    "map_points",
    "packaged_texture_dir",
    "procedural_texture",
    "render",
    "simulate_sequence",
]
