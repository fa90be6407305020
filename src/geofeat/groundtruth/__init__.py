"""Dense ground truth for annotated RGB-D sequences (`geofeat groundtruth`): landmarks -> robust
thin-plate spline -> photometric refinement on a control-point grid -> the authors' TPS file layout."""

from .pipeline import DEFAULT_SPACING_PX, FrameReport, GroundTruthConfig, generate_ground_truth, reference_mask
from .refine import RefineConfig, refine
from .tps import TPS, RobustFit, robust_landmark_tps

__all__ = ["DEFAULT_SPACING_PX", "FrameReport", "GroundTruthConfig", "RefineConfig", "RobustFit", "TPS",
           "generate_ground_truth", "reference_mask", "refine", "robust_landmark_tps"]
