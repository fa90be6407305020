"""`geofeat.extract`: the whole job in one call, keypoints and GeoPatch descriptors of one frame."""

from __future__ import annotations

from .constants import N_KEYPOINTS
from .features import Features
from .frame import RGBDFrame
from .keypoints import detect

#: The detector `extract` uses when none is named: the one that scores best with GeoPatch on every
#: held-out simulated test set measured (BENCHMARKS.md, "GeoKey").
BEST_DETECTOR = "geokey"


def extract(frame: RGBDFrame, n: int = N_KEYPOINTS, detector: str | None = None, descriptor: str = "geopatch",
            radius: float | None = None, depth_config="auto") -> Features:
    """Detect up to `n` keypoints on `frame` and describe them.

    Args:
        frame: the RGB-D frame.
        n: keypoints wanted (>= 1).
        detector: "sift", "geokey" or "geokey=WEIGHTS"; None = `BEST_DETECTOR`.
        descriptor: a `geofeat.make_descriptor` name (default the shipped GeoPatch).
        radius: geodesic radius, metres (None: the descriptor's default, 0.075).
        depth_config: depth profile name or `DepthConfig` (default "auto").

    Returns:
        `Features`: keypoints (N, 2) pixels, descriptors ((N, 128) float32 for GeoPatch), valid (N,).
    """
    from .descriptors import make_descriptor

    keypoints = detect(frame, n, detector=detector or BEST_DETECTOR)
    return make_descriptor(descriptor, radius=radius, depth_config=depth_config).compute(frame, keypoints)
