"""Every correspondence source in one place: `sources.GroundTruth.map` maps target pixels to reference
pixels from the authors' TPS files, the simulator's exact truth (`simulator`) or a landmark spline
(`landmarks`), all with the one spline of `geofeat.tps`; and dense ground truth for annotated RGB-D
sequences (`geofeat groundtruth`): landmarks -> robust thin-plate spline -> photometric refinement on
a control-point grid -> the authors' TPS file layout.

Names are loaded on first use, so that the CLI can read the defaults without importing torch."""

from importlib import import_module

from .defaults import DEFAULT_DEPTH_MARGIN_M, DEFAULT_MARGIN_PX, DEFAULT_SPACING_PX

_WHERE = {
    "FrameReport": "pipeline", "GroundTruthConfig": "pipeline", "generate_ground_truth": "pipeline",
    "reference_mask": "pipeline", "RefineConfig": "photometric", "refine": "photometric",
    "RobustFit": "landmarks", "robust_landmark_tps": "landmarks", "landmark_spline": "landmarks",
    "GroundTruth": "sources", "correct_matches": "sources", "judged_matches": "sources", "load_authors_spline": "sources",
}

__all__ = ["DEFAULT_DEPTH_MARGIN_M", "DEFAULT_MARGIN_PX", "DEFAULT_SPACING_PX", *_WHERE]


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
