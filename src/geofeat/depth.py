"""Depth preprocessing: hole filling, masked smoothing pyramid, back-projection.

All depths are in metres, 0 = missing. Image coordinates follow OpenCV (the centre of the top-left
pixel is (0, 0)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numbers

import cv2
import numpy as np
from numba import njit

from .constants import (DEPTH_PROFILE_NAMES, HOLE_MAX_PERIMETER_PX, IDW_POWER, MESH_SCALE, MIN_FRAME_SIDE_PX,
                        SMOOTH_LEVELS, SMOOTH_WINDOW_PX)
from .frame import check_intrinsics
from .inputs import check_bool, check_positive, check_whole, unmask_depth

FILL_METHODS = ("idw", "simple", "none")


@dataclass(frozen=True)
class DepthConfig:
    """How depth becomes the surface that rays walk on (defaults = the paper's real-data setting).

    Attributes:
        fill: hole filling, "idw" (inverse-distance weighting), "simple" (mean of the hole's
            border) or "none".
        smooth_levels: rounds of masked box smoothing + 2x downscale ("depth two" = 2); 0 = raw.
        mesh_scale: mesh resolution relative to the frame (0.5: a 640x480 frame gives a 320x240 mesh).
        constant: replace the depth by its median everywhere (ablation: a fronto-parallel plane).
        max_perimeter: holes whose border has at least this many pixels stay holes.
    """

    fill: str = "idw"
    smooth_levels: int = SMOOTH_LEVELS
    mesh_scale: float = MESH_SCALE
    constant: bool = False
    max_perimeter: int = HOLE_MAX_PERIMETER_PX

    def __post_init__(self) -> None:
        if self.fill not in FILL_METHODS:
            raise ValueError(f"fill: expected one of {FILL_METHODS}, got {self.fill!r}")
        for name in ("smooth_levels", "max_perimeter"):  # counts: 1.5 rounds of smoothing mean nothing
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
                raise ValueError(f"{name}: must be a whole number >= 0, got {value!r}")
        if isinstance(self.mesh_scale, bool) or not isinstance(self.mesh_scale, numbers.Real) \
                or not 0 < self.mesh_scale <= 1:
            raise ValueError(f"mesh_scale: must be in (0, 1], got {self.mesh_scale!r}")
        # constant="false" (a string from a config file) or 0.0 was taken as it reads in an `if`: "false"
        # replaced the surface by a plane (the ablation) without a word
        object.__setattr__(self, "constant", check_bool(self.constant, "constant"))


#: Named depth profiles (see `depth_profile`): "kinect" is the paper's real-data setting (IDW hole
#: filling, two rounds of masked smoothing, half-resolution mesh); "quantised" is for noise-free depth
#: stored in coarse steps (millimetre PNGs of a close-up surface): one round of smoothing, enough to
#: take the staircase out, on the same half-resolution mesh; "clean" keeps the measured depth (holes
#: still filled) on a full-resolution mesh, for noise-free depth in fine steps such as the
#: simulator's 0.1 mm PNGs. BENCHMARKS.md, "Millimetre depth: the quantised profile".
PROFILES = {
    "kinect": DepthConfig(),
    "quantised": DepthConfig(smooth_levels=1, mesh_scale=0.5),
    "clean": DepthConfig(smooth_levels=0, mesh_scale=1.0),
}
#: Names accepted wherever a depth profile is asked for ("auto" = chosen by `depth_profile`).
PROFILE_NAMES = DEPTH_PROFILE_NAMES
#: `depth_profile` picks "kinect" when the frame's slope noise (`DepthNoise.slope_noise`) is above this.
#: Measured (`benchmarks/depth_profiles.py`): the real Kinect v1 frame 0.52-0.56, Kinect-noise
#: simulations 0.97-0.99, clean simulations 0-0.21 (docs/concepts.md, "How the profile is chosen").
SLOPE_NOISE_THRESHOLD = 0.3
#: `depth_profile` picks "quantised" for low-noise depth stored in steps coarser than this many pixel
#: footprints: on millimetre PNGs of close-up noise-free cloth (0.5-1 footprint) the full-resolution
#: mesh reads the staircase as surface (up to a fifth lower MS than "kinect"), and one round of smoothing
#: ("quantised") scores what "clean" scores on the same scenes in 0.1 mm steps (0.05-0.1 footprints);
#: BENCHMARKS.md, "Depth units" and "Millimetre depth: the quantised profile".
STEP_THRESHOLD = 0.3
#: Fewer measurable 5x5 windows than this: too little surface to measure, "kinect" (the safe choice).
MIN_NOISE_WINDOWS = 500


def mean_focal(K: np.ndarray) -> float:
    """The focal length, pixels, that sizes a pixel's footprint (z / f metres at depth z) where one
    size serves both axes: the mean of fx and fy, so that a camera rolled by a quarter turn (fx and fy
    swap) measures the same (K[0, 0] alone made non-square pixels a fifth larger or smaller by roll)."""
    return 0.5 * (float(K[0, 0]) + float(K[1, 1]))


def depth_steps(depth: np.ndarray, fx: float, fy: float, step_footprints: float) -> tuple[np.ndarray, np.ndarray]:
    """Where an (H, W) depth map (metres, 0 = missing) steps by more than `step_footprints` pixel
    footprints between 4-neighbours: (H, W - 1) bool to the right-hand neighbour, (H - 1, W) bool to
    the neighbour below. The footprint is z / fx across and z / fy down, z the depth of the left or
    upper pixel (a footprint of 1 m where it has none). A surface inclined by an angle a to the image
    plane steps by tan(a) footprints per pixel."""
    depth = np.asarray(depth, np.float32)
    right = np.abs(depth[:, 1:] - depth[:, :-1])  # metres
    right /= np.where(depth > 0, depth / np.float32(fx), np.float32(1.0))[:, :-1]  # in footprints, z / fx
    down = np.abs(depth[1:] - depth[:-1])
    down /= np.where(depth > 0, depth / np.float32(fy), np.float32(1.0))[:-1]  # in footprints, z / fy
    return right > step_footprints, down > step_footprints


def check_profile(profile: str, what: str = "depth_profile") -> str:
    """Return `profile` lower-cased if it names a depth profile, else raise ValueError naming `what`."""
    name = str(profile).strip().lower() if isinstance(profile, str) else None
    if name not in PROFILE_NAMES:
        raise ValueError(f"{what}: expected one of {', '.join(PROFILE_NAMES)}, got {profile!r}")
    return name


def _quadratic_fit_kernel() -> np.ndarray:
    """(5, 5) weights whose correlation with a depth window gives the centre value of the window's
    least-squares quadratic surface z = a + bx + cy + dx^2 + exy + fy^2 (a 2-D Savitzky-Golay filter)."""
    ys, xs = np.mgrid[-2:3, -2:3].astype(np.float64)
    A = np.stack([np.ones(25), xs.ravel(), ys.ravel(), xs.ravel() ** 2, (xs * ys).ravel(), ys.ravel() ** 2], 1)
    return np.linalg.pinv(A)[0].reshape(5, 5)


@dataclass(frozen=True)
class DepthNoise:
    """Noise of a depth map measured on itself.

    Attributes:
        slope_noise: depth noise in units of the pixel footprint (sigma_z / (z / f), f = `mean_focal`): the noise of
            the surface slope between neighbouring pixels, with the depth map's own quantisation
            step (a 16-bit PNG's millimetre) taken out. Dimensionless.
        relative_noise: sigma_z / z (quantisation taken out the same way), dimensionless.
        quantisation_step: the smallest step between the map's depth values (robust: 5th percentile
            of the gaps between distinct values), metres; 0 for continuous depth.
        step_per_footprint: that step over the median pixel footprint: how coarse the stored depth
            is for the walk (a millimetre PNG at 1 m with fx = 525: 0.53).
        hole_fraction: fraction of the frame's pixels without depth.
        windows: number of 5x5 windows (all pixels with depth) the statistics come from.
    """

    slope_noise: float
    relative_noise: float
    quantisation_step: float
    step_per_footprint: float
    hole_fraction: float
    windows: int


#: E[min(x^2, q^2)] / sigma^2 for a normal x winsorised at its 95th percentile of |x| (q = 1.96 sigma):
#: divides the winsorised mean square back to sigma^2.
_WINSOR_95 = 0.9135


def _noise_rms(residual: np.ndarray, floor: np.ndarray) -> float:
    """sqrt(winsorised mean of residual^2 (95th percentile), Gaussian-corrected, minus mean floor^2)."""
    r2 = residual**2
    r2 = np.minimum(r2, np.quantile(r2, 0.95))
    return float(np.sqrt(max(r2.mean() / _WINSOR_95 - np.mean(floor**2), 0.0)))


#: A depth map with at least this many measurable 5 x 5 windows is measured on the windows centred on
#: every second row and column (a quarter of them), in about 60 % of the time. On 217 frames (the
#: shipped Kinect frame and simulated ones, 12 000-270 000 windows) the slope noise moved by at most
#: 0.015 and no profile changed (BENCHMARKS.md, "Millimetre depth: the quantised profile").
SAMPLED_WINDOWS = 40_000


class _NoiseMeasure:
    """The parts of `depth_noise` on one (H, W) depth map, each computed on first use, so that
    `depth_profile` can stop at the cheapest one, the window count (the quantisation step takes about
    2 ms on a 640 x 480 frame, the quadratic fits about 2-3 ms more). The footprint and the fits are
    measured on `sample`: every window, or from `SAMPLED_WINDOWS` on a quarter of them."""

    def __init__(self, depth: np.ndarray, K: np.ndarray) -> None:
        raw = _check_depth_map(depth, finite=False)
        self.K = check_intrinsics(K)
        self.depth = raw.astype(np.float64)
        valid = np.isfinite(self.depth) & (self.depth > 0)  # NaN and inf (disparity 0) are missing too
        self.inner = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8), borderType=cv2.BORDER_CONSTANT,
                               borderValue=0) > 0
        self.windows = int(self.inner.sum())
        self.sample = self.inner
        if self.windows >= SAMPLED_WINDOWS:
            self.sample = np.zeros_like(self.inner)
            self.sample[::2, ::2] = self.inner[::2, ::2]
        self.holes = float(1.0 - valid.mean())
        # the distinct values in the map's own type (float32 for frames: sorting them costs a third of
        # float64), converted exactly to float64 before the gaps are taken
        gaps = np.diff(np.unique(raw[valid]).astype(np.float64))
        self.step = float(np.quantile(gaps, 0.05)) if len(gaps) else 0.0
        self._footprint = None

    @property
    def footprint(self) -> np.ndarray:
        """Lateral size of a pixel at each sampled window's centre, z / f (`mean_focal`), metres."""
        if self._footprint is None:
            self._footprint = self.depth[self.sample] / mean_focal(self.K)
        return self._footprint

    def step_per_footprint(self) -> float:
        """The quantisation step over the median pixel footprint (needs windows > 0)."""
        return float(self.step / np.median(self.footprint))

    def slope_noise(self) -> float:
        """sigma_z / (z / f) from the centre residuals of the 5 x 5 quadratic fits (needs windows > 0)."""
        kernel = _quadratic_fit_kernel()
        fitted = cv2.filter2D(self.depth, -1, kernel, borderType=cv2.BORDER_REFLECT)
        residual = self.depth[self.sample] - fitted[self.sample]
        residual /= np.sqrt(1.0 - kernel[2, 2])
        sigma_q = self.step / np.sqrt(12.0)
        return _noise_rms(residual / self.footprint, sigma_q / self.footprint)


def depth_noise(depth: np.ndarray, K: np.ndarray) -> DepthNoise:
    """Measure the noise of an (H, W) depth map (metres, 0, NaN or inf = missing) with intrinsics K (3, 3).

    Every 5x5 window whose pixels all have depth gets a least-squares quadratic surface; the
    residual at its centre, divided by sqrt(1 - h0) (h0 = the fit's centre weight), estimates the
    depth noise without the surface's own curvature. Its root mean square (squares winsorised at
    their 95th percentile against depth discontinuities, corrected to sigma for Gaussian noise)
    gives sigma; the variance of the depth map's quantisation (step^2 / 12) is subtracted, so that
    millimetre PNGs of clean depth read as clean at any distance, while sensor noise (Kinect's
    disparity steps are several times coarser than a millimetre at a metre) remains.
    """
    measure = _NoiseMeasure(depth, K)
    if measure.windows == 0:
        return DepthNoise(float("nan"), float("nan"), measure.step, float("nan"), measure.holes, 0)
    slope = measure.slope_noise()
    # residual / z = (residual / footprint) / f, and the same for the floor: the relative noise is
    # the slope noise over f (one winsorised quantile fewer)
    return DepthNoise(slope, slope / mean_focal(measure.K), measure.step, measure.step_per_footprint(),
                      measure.holes, measure.windows)


def depth_profile(frame) -> str:
    """The depth profile for `frame` (an RGBDFrame): "kinect" when its measured slope noise
    (`depth_noise`) exceeds `SLOPE_NOISE_THRESHOLD` or when too little surface can be measured;
    otherwise "quantised" when its depth is stored in steps coarser than `STEP_THRESHOLD` pixel
    footprints, else "clean". The window count is tested first: a frame it decides needs no
    quadratic fits."""
    if not (hasattr(frame, "depth") and hasattr(frame, "K")):
        raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__} (for a bare depth map, "
                        "use geofeat.depth_noise(depth, K))")
    measure = _NoiseMeasure(frame.depth, frame.K)
    if measure.windows < MIN_NOISE_WINDOWS or measure.slope_noise() > SLOPE_NOISE_THRESHOLD:
        return "kinect"
    return "quantised" if measure.step_per_footprint() > STEP_THRESHOLD else "clean"


def sequence_depth_profile(seq, requested: str | None = None, frame=None) -> str:
    """The concrete depth profile ("kinect", "quantised" or "clean") for a whole sequence (a
    `geofeat.io.Sequence`): `requested` when it names one; None (the default) the sequence's
    geofeat.json `depth_profile` when that names one, else measured; "auto" measured, whatever
    geofeat.json says. Measured = the one `depth_profile` picks on `frame` (default: the sequence's
    reference frame). One profile per sequence keeps every frame of it on the same kind of mesh."""
    if requested is None:
        name = check_profile(getattr(seq, "depth_profile", "auto"), "geofeat.json depth_profile")
    else:
        name = check_profile(requested)
    if name == "auto":
        name = depth_profile(frame if frame is not None else seq.frame(seq.reference))
    return name


def resolve_depth_config(depth_config, frame=None) -> DepthConfig:
    """A `DepthConfig`, or a profile name ("auto", "kinect", "quantised", "clean") -> the DepthConfig
    to use on `frame` ("auto" needs the frame and measures it)."""
    if isinstance(depth_config, DepthConfig):
        return depth_config
    if not isinstance(depth_config, str):
        raise TypeError(f"depth_config: expected a DepthConfig or a profile name, got {type(depth_config).__name__}")
    name = check_profile(depth_config, "depth_config")
    if name == "auto":
        if frame is None:
            raise ValueError("depth_config: 'auto' needs the frame to measure its depth noise")
        name = depth_profile(frame)
    return PROFILES[name]


def depth_config_name(config: DepthConfig) -> str:
    """A DepthConfig as errors name it: its profile's name ("'kinect'") when it is one, else itself."""
    name = next((n for n, c in PROFILES.items() if c == config), None)
    return repr(name) if name is not None else repr(config)


def _check_depth_map(depth, what: str = "depth", finite: bool = True) -> np.ndarray:
    """An (H, W) numeric depth map as an array (ValueError / TypeError naming `what` otherwise; with
    `finite`, NaN or infinite values are refused too: missing depth is 0 here, and so are the masked
    pixels of a masked array)."""
    depth = np.asarray(unmask_depth(depth))
    if depth.ndim != 2:
        raise ValueError(f"{what}: expected an (H, W) depth map, got shape {depth.shape}")
    if depth.size == 0:
        raise ValueError(f"{what}: empty, shape {depth.shape}")
    if depth.dtype.kind not in "biuf":
        raise TypeError(f"{what}: expected a numeric depth map, got dtype {depth.dtype}")
    if finite and depth.dtype.kind == "f" and not np.isfinite(depth).all():
        raise ValueError(f"{what}: contains NaN or infinite values; use 0 for missing depth")
    return depth


def fill_holes(
    depth: np.ndarray,
    max_perimeter: int = HOLE_MAX_PERIMETER_PX,
    method: str = "idw",
    power: float = IDW_POWER,
) -> np.ndarray:
    """Fill small holes of an (H, W) depth map (metres, 0 = missing).

    A hole is a 4-connected region of zeros that does not touch the image border. Holes whose
    border (the valid pixels 8-adjacent to them) has fewer than `max_perimeter` pixels are filled:
    "idw" gives each hole pixel sum(w z) / sum(w) over the border pixels with w = 1 / d**power
    (d = pixel distance); "simple" gives the mean border depth. Larger holes stay 0.

    Returns a new (H, W) float32 array.
    """
    if method not in FILL_METHODS:
        raise ValueError(f"method: expected one of {FILL_METHODS}, got {method!r}")
    check_whole(max_perimeter, "max_perimeter", 0)
    check_positive(power, "power")  # NaN wrote NaN into the holes, a negative one favoured far pixels
    depth = _check_depth_map(depth)  # an empty map crashes OpenCV's labelling (segfault)
    out = np.array(depth, dtype=np.float32, copy=True)
    if method == "none":
        return out
    missing = out <= 0
    # 4-connected regions of missing pixels (the components that scipy.ndimage.label gives), and
    # their bounding boxes in one compiled pass (OpenCV's labelling "with stats" also computes areas
    # and centroids, about three times the labelling's own time: benchmarks/bench_fill_holes.py)
    n, labels = cv2.connectedComponents(missing.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    _fill_enclosed_holes(out, labels, _label_boxes(labels, n), int(max_perimeter), float(power), method == "simple")
    return out


@njit(cache=True)
def _label_boxes(labels, n):  # pragma: no cover - compiled
    """(n, 4) int64 bounding boxes (x0, y0, x1, y1), end-exclusive, of the labels 1..n-1 of an (H, W)
    int32 label image (row 0, the background label, and a label without pixels keep x0 = W, y0 = H,
    x1 = y1 = 0)."""
    H, W = labels.shape
    boxes = np.zeros((n, 4), np.int64)
    boxes[:, 0] = W
    boxes[:, 1] = H
    for y in range(H):
        for x in range(W):
            i = labels[y, x]
            if i == 0:  # the pixels with depth: no box needed
                continue
            if x < boxes[i, 0]:
                boxes[i, 0] = x
            if y < boxes[i, 1]:
                boxes[i, 1] = y
            if x + 1 > boxes[i, 2]:
                boxes[i, 2] = x + 1
            if y + 1 > boxes[i, 3]:
                boxes[i, 3] = y + 1
    return boxes


@njit(cache=True, error_model="numpy")
def _fill_enclosed_holes(out, labels, boxes, max_perimeter, power, simple):  # pragma: no cover - compiled
    """`fill_holes`' loop over the labelled regions, compiled (as a Python loop over a frame's holes,
    with a few array operations per hole and one power per pair of hole and border pixels, it was most
    of `fill_holes`' time: 2.5 against 1.0 ms now on the Kinect frame, benchmarks/bench_fill_holes.py).

    out: (H, W) float32 depth, written in place; labels: (H, W) int32, 0 = pixels with depth, i >= 1 the
    i-th 4-connected region of missing pixels; boxes: (n, 4) their bounding boxes (x0, y0, x1, y1),
    end-exclusive (`_label_boxes`). A region is filled when it does not touch the image border and fewer than
    `max_perimeter` pixels with depth are 8-adjacent to it (its border): IDW with weights
    1 / d**power over the border pixels (d in pixels), or the border's mean when `simple`."""
    H, W = out.shape
    size = max(max_perimeter, 1)
    by = np.empty(size, np.int64)
    bx = np.empty(size, np.int64)
    bz = np.empty(size, np.float64)
    for index in range(1, boxes.shape[0]):
        x0, y0, x1, y1 = boxes[index, 0], boxes[index, 1], boxes[index, 2], boxes[index, 3]
        if y0 == 0 or x0 == 0 or y1 == H or x1 == W:
            continue  # touches the border: not an enclosed hole
        count = 0
        for y in range(y0 - 1, y1 + 1):  # the border lies in the box grown by one pixel
            for x in range(x0 - 1, x1 + 1):
                if labels[y, x] != 0:
                    continue
                adjacent = False
                for yy in range(y - 1, y + 2):
                    for xx in range(x - 1, x + 2):
                        if 0 <= yy < H and 0 <= xx < W and labels[yy, xx] == index:
                            adjacent = True
                if adjacent:
                    if count < size:
                        by[count], bx[count], bz[count] = y, x, out[y, x]
                    count += 1
        if count >= max_perimeter:
            continue
        mean = 0.0
        if simple:
            for i in range(count):
                mean += bz[i]
            mean /= count
        # the IDW weights by squared pixel distance, d2 <= h^2 + w^2 in this box: one power per
        # distance instead of one per (hole pixel, border pixel) pair (the same values)
        weight = np.empty(0)
        if not simple:
            weight = np.empty((y1 - y0) ** 2 + (x1 - x0) ** 2 + 1)
            for d2 in range(1, weight.shape[0]):
                weight[d2] = float(d2) ** (-power / 2.0)
        for y in range(y0, y1):
            for x in range(x0, x1):
                if labels[y, x] != index:
                    continue
                if simple:
                    out[y, x] = mean
                    continue
                num = 0.0
                den = 0.0
                for i in range(count):
                    dy, dx = y - by[i], x - bx[i]
                    w = weight[dy * dy + dx * dx]
                    num += w * bz[i]
                    den += w
                out[y, x] = num / den


def _masked_box_mean(depth: np.ndarray, window: int) -> np.ndarray:
    """Mean over the valid pixels of a centred window, written at valid pixels only."""
    valid = (depth > 0).astype(np.float32)
    num = cv2.boxFilter(depth * valid, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    den = cv2.boxFilter(valid, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    out = np.where(valid > 0, num / np.maximum(den, 1e-12), 0.0)
    return out.astype(np.float32)


#: A 2x2 block of the smoothing pyramid keeps a depth when at least this many of its pixels have one
#: (`_halve`; the GPU pyramid, `geofeat.gpu.smooth_depth_torch`, reads it too).
HALVE_MIN_VALID = 2
#: A resized depth pixel keeps a depth when at least this share of its interpolation weight falls on
#: pixels with depth (`_masked_resize`, `smooth`; the GPU pyramid reads it too).
RESIZE_MIN_WEIGHT = 0.5


def _halve(depth: np.ndarray) -> np.ndarray:
    """2x downscale by 2x2 block averaging of the valid pixels; a block with fewer than 2 valid
    pixels is missing (so the surface's outline moves by at most one pixel per level)."""
    H, W = depth.shape
    d = depth[: H // 2 * 2, : W // 2 * 2]
    a, b, c, e = d[0::2, 0::2], d[0::2, 1::2], d[1::2, 0::2], d[1::2, 1::2]  # the 2x2 blocks' corners
    count = (a > 0).astype(np.int64) + (b > 0) + (c > 0) + (e > 0)
    total = (a + b) + (c + e)  # the order of numpy's sum over the block's axes: the same rounding
    return np.where(count >= HALVE_MIN_VALID, total / np.maximum(count, 1), 0.0).astype(np.float32)


def _masked_resize(depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bilinear resize to size = (W, H) of the valid pixels; an output pixel is missing when less
    than half of its interpolation weight falls on valid pixels."""
    if depth.shape[::-1] == tuple(size):
        return depth.astype(np.float32)
    valid = (depth > 0).astype(np.float32)
    num = cv2.resize(depth * valid, size, interpolation=cv2.INTER_LINEAR)
    den = cv2.resize(valid, size, interpolation=cv2.INTER_LINEAR)
    return np.where(den >= RESIZE_MIN_WEIGHT, num / np.maximum(den, 1e-12), 0.0).astype(np.float32)


def smooth(
    depth: np.ndarray,
    levels: int = SMOOTH_LEVELS,
    out_scale: float = MESH_SCALE,
    window: int = SMOOTH_WINDOW_PX,
) -> np.ndarray:
    """Masked smoothing pyramid: `levels` rounds of (masked `window` box mean, 2x downscale),
    then a masked bilinear resize to `out_scale` times the input size.

    Args:
        depth: (H, W) metres, 0 = missing.
    Returns:
        (max(2, round(H * out_scale)), max(2, round(W * out_scale))) float32 metres, 0 = missing (at least
        2 x 2: a mesh needs one cell). All 0 for a map under `MIN_FRAME_SIDE_PX` (2) pixels high or
        wide (`too_thin_for_surface`).
    """
    depth = _check_depth_map(depth)
    check_whole(levels, "levels", 0)
    check_whole(window, "window", 1)
    check_positive(out_scale, "out_scale")
    H, W = depth.shape
    size = (max(2, int(round(W * out_scale))), max(2, int(round(H * out_scale))))
    if too_thin_for_surface(depth.shape):
        return np.zeros(size[::-1], np.float32)
    d = np.asarray(depth, dtype=np.float32)
    halvings = 0
    for _ in range(levels):
        if min(d.shape) < 2 * window:
            break
        d = _halve(_masked_box_mean(d, window))
        halvings += 1
    matrices = pyramid_resampling(depth.shape, d.shape, halvings, size)
    if matrices is None:  # the pyramid covers the frame: the resize's own mapping is the exact one
        return _masked_resize(d, size)
    Ry, Rx = matrices
    valid = (d > 0).astype(np.float64)
    num, den = Ry @ (d * valid) @ Rx.T, Ry @ valid @ Rx.T
    return np.where(den >= RESIZE_MIN_WEIGHT, num / np.maximum(den, 1e-12), 0.0).astype(np.float32)


def too_thin_for_surface(shape: tuple[int, ...]) -> bool:
    """Whether an (H, W) depth map is under `MIN_FRAME_SIDE_PX` pixels high or wide: one row (or
    column) of depth samples holds no surface across it. Stretched into the mesh's smallest grid (2 x 2
    vertices, one cell) it made one: faces of a made-up flat strip, on which the rays of a 1 x 1 or
    1 x 640 frame's keypoints walked and their patches were valid. `smooth` (and the GPU's
    `smooth_depth_torch`) give such a map no depth at all, so its mesh has no face."""
    return min(int(shape[0]), int(shape[1])) < MIN_FRAME_SIDE_PX


def _axis_interpolation(n_in: int, n_out: int, step: float) -> np.ndarray:
    """(n_out, n_in) linear interpolation weights of output sample i at input position
    (i + 0.5) step - 0.5 (pixel centres kept, as `cv2.resize`), clamped to the input's ends."""
    j = np.clip((np.arange(n_out) + 0.5) * step - 0.5, 0.0, n_in - 1.0)
    j0 = np.minimum(np.floor(j).astype(np.int64), n_in - 1)
    j1 = np.minimum(j0 + 1, n_in - 1)
    w1 = j - j0
    R = np.zeros((n_out, n_in))
    np.add.at(R, (np.arange(n_out), j0), 1.0 - w1)
    np.add.at(R, (np.arange(n_out), j1), w1)
    return R


def pyramid_resampling(shape: tuple[int, int], smoothed: tuple[int, ...], halvings: int,
                       size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """None when the smoothing pyramid's map `smoothed` (h, w) covers the (H, W) frame `shape`
    (h 2^halvings = H and the same for w); else the (Hm, Wm) = `size`[::-1] interpolation matrices
    Ry (Hm, h) and Rx (Wm, w) that put the map back where it belongs. Each 2x halving drops an odd
    last row or column, so a frame whose sides are not multiples of 2^halvings (643 x 483 with the
    "kinect" profile's two) keeps a map of only its top-left 640 x 480 pixels; a plain resize
    stretched it over the whole frame, and the mesh was off by up to a few pixels towards the far
    edges (a tilted plane's depth: 3 mm median error at 643 x 483). Shared by the CPU and GPU pyramids."""
    H, W = shape
    h, w = int(smoothed[0]), int(smoothed[1])
    if (h << halvings, w << halvings) == (H, W):
        return None
    Wm, Hm = size
    return (_axis_interpolation(h, Hm, (H / Hm) / (1 << halvings)),
            _axis_interpolation(w, Wm, (W / Wm) / (1 << halvings)))


def scale_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics of an image resized by (sx, sy), pixel centres kept consistent:
    x' = (x + 0.5) * sx - 0.5."""
    Ks = np.array(K, dtype=np.float64, copy=True)
    Ks[0, 0] *= sx
    Ks[0, 1] *= sx
    Ks[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    Ks[1, 1] *= sy
    Ks[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return Ks


def backproject(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Back-project an (H, W) depth map (metres) with intrinsics K to (H, W, 3) camera-frame points
    in metres, the inverse of u = (fx X + s Y) / Z + cx, v = fy Y / Z + cy (s = K[0, 1], the skew);
    missing pixels (depth 0, negative, NaN or inf) give NaN."""
    depth = _check_depth_map(depth, finite=False)
    K = check_intrinsics(K)
    H, W = depth.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = np.where(np.isfinite(depth) & (depth > 0), depth.astype(np.float64), np.nan)
    y_over_z = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y_over_z) / K[0, 0] * z
    return np.stack([x, y_over_z * z, z], axis=-1)


def filled_depth(depth: np.ndarray, config: DepthConfig = DepthConfig()) -> np.ndarray:
    """The first step of `preprocess_depth`, at the frame's resolution: small holes filled
    (`fill_holes`), or for `config.constant` the median depth everywhere. (H, W) float32 metres."""
    depth = np.asarray(depth, dtype=np.float32)
    if config.constant:
        valid = depth > 0
        return np.full_like(depth, np.median(depth[valid]) if valid.any() else 0.0)
    return fill_holes(depth, config.max_perimeter, config.fill)


def preprocess_depth(depth: np.ndarray, config: DepthConfig = DepthConfig()) -> np.ndarray:
    """Full depth preprocessing of an (H, W) metre depth map into the mesh-resolution depth map
    (see `DepthConfig`): `filled_depth`, then the smoothing pyramid (`smooth`). Returns (Hm, Wm)
    float32 metres, 0 = missing."""
    return smooth(filled_depth(depth, config), config.smooth_levels, config.mesh_scale)
