"""Default parameters of geofeat, in one place (values from the paper unless said otherwise)."""

#: Geodesic support radius of a polar patch, metres (paper: 75 mm on real data).
DEFAULT_RADIUS_M = 0.075
#: Number of angular bins (patch columns) of a polar patch.
N_ANGLES = 32
#: Number of radial rings (patch rows) of a polar patch; ring i sits at (i + 1) * radius / N_RINGS.
N_RINGS = 32
#: Number of keypoints detected per frame by default (any detector).
N_KEYPOINTS = 2048
#: Depth PNG unit in metres (public datasets store millimetres).
DEPTH_SCALE_M = 0.001
#: Holes in the depth map whose boundary is shorter than this many pixels are filled.
HOLE_MAX_PERIMETER_PX = 400
#: Exponent of the inverse-distance weighting used to fill depth holes (authors' value).
IDW_POWER = 2.3
#: Mesh resolution relative to the input frame (authors: 0.5 for real data).
MESH_SCALE = 0.5
#: Number of masked-smoothing / 2x-downscale rounds of the depth pyramid ("depth two").
SMOOTH_LEVELS = 2
#: Side of the masked box filter of each pyramid round, pixels.
SMOOTH_WINDOW_PX = 7
#: A mesh triangle is cut when an edge is longer than this many times the lateral size of a
#: mesh pixel at that depth (about an 83 degree slope): this keeps rays off the background.
MAX_EDGE_STRETCH = 8.0
#: Depth profile names: "auto" (chosen from the frame's measured depth noise), "kinect", "quantised",
#: "clean" (see `geofeat.depth.PROFILES`).
DEPTH_PROFILE_NAMES = ("auto", "kinect", "quantised", "clean")
#: Depths above this many metres are taken as a unit mistake (millimetres passed as metres).
MAX_PLAUSIBLE_DEPTH_M = 50.0
#: Gaussian blur applied to the gray image before sampling polar patches, full-resolution pixels.
SAMPLING_BLUR_PX = 1.0
#: The fewest pixels a frame needs across each axis for a keypoint on it to be described: a single
#: row or column holds no neighbourhood across it (no image gradient; no surface: the mesh of its
#: depth has no face), so every descriptor marks its keypoints invalid, with a warning.
MIN_FRAME_SIDE_PX = 2
