"""One validator per kind of input, used by every command and by the readers in `geofeat.io`.

Each raises ValueError with a one-line message naming the file (or option) and what to change:
`geofeat.json`, the depth scale (plausible median depth), the intrinsics (plausible for the image
size), landmark csv files, reference-frame names, and the one rule for the geodesic radius.
"""

from __future__ import annotations

import json
import math
import numbers
import os
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .constants import DEFAULT_RADIUS_M, DEPTH_PROFILE_NAMES

#: Median depth (metres) of a frame must lie in this range at the depth scale used.
PLAUSIBLE_MEDIAN_DEPTH_M = (0.05, 50.0)
#: A sequence whose median depth (metres) lies outside this range, though plausible, is warned about
#: (`warn_depth_units`): close-up or far scenes exist, but a depth scale off by 10x is likelier. The far
#: end is an RGB-D camera's range (Kinect v2: 4.5 m): 0.1 mm PNGs (what `simulate` writes) read as
#: millimetres put a cloth at 0.48-1.03 m 4.8-10.3 m away, which a bound of 20 m let through.
USUAL_MEDIAN_DEPTH_M = (0.15, 4.5)
#: Focal lengths must lie between these multiples of the larger image side.
PLAUSIBLE_FOCAL_SIDES = (0.1, 20.0)
#: A principal point farther than this fraction of the image size from its centre is warned of (RGBDFrame).
MAX_CENTRE_OFFSET = 0.2
#: ... and one at least this fraction from its centre but within `TRANSPOSED_CENTRE_OFFSET` of the centre of
#: the image transposed (W x H), as a transposed frame of a 4:3 (or 5:4) camera puts it.
MIN_TRANSPOSED_OFFSET, TRANSPOSED_CENTRE_OFFSET = 0.1, 0.05
#: Geodesic radius (metres) must lie in this range.
PLAUSIBLE_RADIUS_M = (0.001, 2.0)
#: The largest depth scale accepted, metres per depth-PNG unit.
MAX_DEPTH_SCALE_M = 10.0
#: Whole name tokens (split on _ - . and spaces) that mark the reference frame, optionally with digits.
REFERENCE_TOKEN = re.compile(r"^(master|ref|reference)\d*$")
CONFIG_KEYS = ("depth_scale", "depth_profile", "radius")
#: Where a depth scale is set, for the messages that ask to set it: the command line, Python, the folder.
DEPTH_SCALE_OPTIONS = ("--depth-scale on the command line, depth_scale= in Python (read_frame, read_sequence), "
                       "or depth_scale in geofeat.json")


def _positive_number(value: Any, what: str) -> float:
    # numbers.Real: Python and numpy ints and floats (np.float32(3.0) is a number too); not bool
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{what}: expected a positive number, got {value!r}")
    return float(value)


def read_config(folder: str | Path) -> dict:
    """The folder's optional `geofeat.json`, validated: a JSON object whose `depth_scale` and `radius` are
    positive numbers and whose `depth_profile` is a known profile name. Other keys are kept as they are,
    except one that names a depth, scale, unit, radius or profile but is none of `CONFIG_KEYS`
    (`depthScale`, `depth_unit`): that is a ValueError, as it was ignored and the depth read in
    millimetres without a word."""
    path = Path(folder) / "geofeat.json"
    if not path.is_file():
        return {}
    try:
        config = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(config, dict):
        raise ValueError(f"{path}: expected a JSON object like {{\"depth_scale\": 0.001}}, got a {type(config).__name__}")
    near = [k for k in config if k not in CONFIG_KEYS
            and any(w in re.sub(r"[^a-z]", "", str(k).lower()) for w in ("depth", "scale", "unit", "radius", "profile"))]
    if near:
        raise ValueError(f"{path}: unknown key {near[0]!r}; geofeat reads {', '.join(CONFIG_KEYS)} (depth_scale: metres "
                         "per depth-PNG unit, e.g. 0.001 for millimetres)")
    if "depth_scale" in config:
        check_depth_scale(config["depth_scale"], f"{path}: depth_scale")
    if "radius" in config:
        check_radius(_positive_number(config["radius"], f"{path}: radius"), f"{path}: radius")
    profile = config.get("depth_profile", "auto")
    if not isinstance(profile, str) or profile.strip().lower() not in DEPTH_PROFILE_NAMES:
        raise ValueError(f"{path}: depth_profile: expected one of {', '.join(DEPTH_PROFILE_NAMES)}, got {profile!r}")
    return config


def check_radius(radius: float, what: str = "--radius") -> float:
    """A geodesic radius in metres, within `PLAUSIBLE_RADIUS_M`."""
    radius = _positive_number(radius, what)
    lo, hi = PLAUSIBLE_RADIUS_M
    if not lo <= radius <= hi:
        raise ValueError(f"{what}: {radius:g} m is not a plausible geodesic radius (expected {lo:g}-{hi:g} m, "
                         f"default {DEFAULT_RADIUS_M})")
    return radius


def resolve_radius(radius: float | None, seq) -> float:
    """The one rule for the geodesic radius of a sequence: the command's `--radius` when given, else
    the sequence's geofeat.json `radius`, else 0.075 m (`Sequence.radius` holds the last two)."""
    if radius is not None:
        return check_radius(radius)
    return check_radius(seq.radius, f"{seq.folder / 'geofeat.json'}: radius")


def check_depth_scale(depth_scale: float, what: str = "--depth-scale") -> float:
    """A depth scale (metres per depth-PNG unit): a positive number of at most `MAX_DEPTH_SCALE_M` (a
    larger one turns 16-bit depth into kilometres, or into inf)."""
    depth_scale = _positive_number(depth_scale, what)
    if depth_scale > MAX_DEPTH_SCALE_M:
        raise ValueError(f"{what}: {depth_scale:g} m per depth unit is implausible (at most {MAX_DEPTH_SCALE_M:g}; "
                         "millimetre PNGs: 0.001)")
    return depth_scale


def check_positive(value: float, what: str) -> float:
    """A positive finite number (a threshold, a size): ValueError naming `what` otherwise (NaN and inf too)."""
    return _positive_number(value, what)


def check_non_negative(value: float, what: str) -> float:
    """A finite number >= 0 (a weight that 0 turns off, a radius that 0 disables): ValueError naming
    `what` otherwise (NaN, inf and bool too)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{what}: expected a number >= 0, got {value!r}")
    return float(value)


def check_whole(value: Any, what: str, minimum: int = 1) -> int:
    """A whole number (Python or numpy int, not bool) >= `minimum`: a count, an index, a seed;
    ValueError naming `what` otherwise (2.5 and "3" too)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{what}: expected a whole number >= {minimum}, got {value!r}")
    return int(value)


def check_bool(value: Any, what: str) -> bool:
    """True or False (Python's or numpy's bool); ValueError naming `what` otherwise: a truthy string
    such as "no", or 1, was taken for True without a word."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{what}: expected True or False, got {value!r}")
    return bool(value)


def check_in_range(value: Any, what: str, lo: float, hi: float) -> float:
    """A real number (Python or numpy, not bool) from `lo` to `hi`, both included; ValueError naming
    `what` otherwise (NaN, a string such as "0.5", None too)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not lo <= value <= hi:
        raise ValueError(f"{what}: expected a number in [{lo:g}, {hi:g}], got {value!r}")
    return float(value)


def check_weights_path(weights: Any, what: str = "weights", shipped: str = "None") -> Any:
    """A weights file name: None (the shipped weights) or a path (str or os.PathLike) that is not
    empty or blank; ValueError naming `what` otherwise. `shipped` says how the shipped weights are
    asked for where `what` is given (None in Python, the bare name on the command line): "" was
    read as the current folder ("no GeoPatch checkpoint at .")."""
    if weights is None:
        return None
    if not isinstance(weights, (str, os.PathLike)):
        raise ValueError(f"{what}: expected the path of a weights file ({shipped}: the shipped weights), "
                         f"got {type(weights).__name__} {weights!r}")
    if not str(weights).strip():
        raise ValueError(f"{what}: an empty path; expected the path of a weights file ({shipped}: the shipped weights)")
    return weights


#: A thread count above this multiple of the machine's CPUs is refused (`check_threads`).
MAX_THREADS_PER_CPU = 64


def check_threads(value: Any, what: str = "threads", unit: str = "threads") -> int:
    """A thread (or process: `unit`) count: a whole number from 1 to `MAX_THREADS_PER_CPU` times
    `os.cpu_count()`; ValueError naming `what` otherwise. `GeoPatch(threads=100000)` asked torch, ONNX
    Runtime or OpenVINO for 100000 threads, which killed the process rather than raising an error."""
    count = check_whole(value, what, 1)
    most = MAX_THREADS_PER_CPU * (os.cpu_count() or 1)
    if count > most:
        raise ValueError(f"{what}: {count} {unit} is far more than this machine's {os.cpu_count() or 1} CPUs can run "
                         f"(expected 1 to {most}, at most {MAX_THREADS_PER_CPU} per CPU)")
    return count


def error_summary(error: BaseException, limit: int = 200) -> str:
    """"TypeName: first line of the message" (at most `limit` characters of it), for a ValueError
    that wraps an error from a library (unpickling, ONNX Runtime) in words naming the user's file."""
    text = str(error).splitlines()[0] if str(error) else ""
    return f"{type(error).__name__}: {text[:limit]}"


def _median_depth(depth_m: np.ndarray) -> float | None:
    """The median of the valid (finite, > 0) depths, None when there is none."""
    depth_m = np.asarray(depth_m)
    valid = depth_m[np.isfinite(depth_m) & (depth_m > 0)]
    return float(np.median(valid)) if valid.size else None


#: The units depth maps come in, with their depth scales (metres per unit), for `unit_readings`: 5000 a
#: metre is the TUM RGB-D benchmark's (and ICL-NUIM's, ETH3D's); without it, such a scene at 1 m read as
#: millimetres (5 m) was given the tenths of a millimetre's reading, 0.5 m, which no check then questioned.
DEPTH_UNITS = (("millimetres", 0.001), ("centimetres", 0.01), ("tenths of a millimetre", 0.0001),
               ("fifths of a millimetre (5000 a metre, as TUM RGB-D stores depth)", 0.0002))


def unit_readings(raw_median: float, bounds: tuple[float, float] = PLAUSIBLE_MEDIAN_DEPTH_M,
                  skip: float | None = None) -> str:
    """What a depth map's median `raw_median` (in its own units) reads as in the units of `DEPTH_UNITS`
    (but the depth scale `skip`), the readings within `bounds` (metres) only: "read as millimetres
    0.80 m (depth_scale=0.001), or as centimetres 8.00 m (depth_scale=0.01)"; "" when none is. 80 cm
    was taken for millimetres, and dividing it by 1000 would give 8 cm."""
    lo, hi = bounds
    readings = [f"as {unit} {raw_median * scale:.2f} m (depth_scale={scale:g})" for unit, scale in DEPTH_UNITS
                if scale != skip and lo <= raw_median * scale <= hi]
    return "read " + ", or ".join(readings) if readings else ""


class DepthUnitsWarning(UserWarning):
    """A sequence's depth lies at a plausible but unusual distance for its depth scale (see
    `warn_depth_units`): a hint to check the depth units, never an error."""


_warned_depth_units: set[tuple[str, float]] = set()


def warn_depth_units(depth_m: np.ndarray, depth_scale: float, where: str, key: str | None = None) -> None:
    """Warn (`DepthUnitsWarning`) when the median valid depth (metres, after scaling) lies outside
    `USUAL_MEDIAN_DEPTH_M`: `--depth-scale 0.0001` on millimetre PNGs gives a scene 10x too near
    (0.1 m) that `check_depth_plausible` lets through. Close-up (macro) data may be right, so it is
    not an error. Once per `key` (default `where`: a sequence folder, a file) and depth scale in a
    process, however often the sequence is read."""
    median = _median_depth(depth_m)
    lo, hi = USUAL_MEDIAN_DEPTH_M
    if median is None or lo <= median <= hi:
        return
    seen = (key or where, float(depth_scale))
    if seen in _warned_depth_units:
        return
    _warned_depth_units.add(seen)
    readings = unit_readings(median / depth_scale, USUAL_MEDIAN_DEPTH_M, skip=depth_scale)  # cm read as mm: as cm
    warnings.warn(f"{where}: median depth {median:.3g} m at depth scale {depth_scale:g} m per unit is "
                  f"{'nearer' if median < lo else 'farther'} than usual ({lo:g}-{hi:g} m); unless the scene really is that "
                  f"{'near' if median < lo else 'far'}, "
                  f"check the depth scale ({DEPTH_SCALE_OPTIONS}) against the units of the depth PNGs "
                  f"(millimetres: 0.001){f'; {readings}' if readings else ''}", DepthUnitsWarning, stacklevel=2)


def check_depth_plausible(depth_m: np.ndarray, depth_scale: float, where: str) -> None:
    """The median of the valid depths (metres, after scaling) must be plausible, else the depth scale is
    wrong (metres stored where millimetres are expected, or the other way round)."""
    median = _median_depth(depth_m)
    if median is None:
        return  # a frame without depth is reported by the command that needs depth
    lo, hi = PLAUSIBLE_MEDIAN_DEPTH_M
    if not lo <= median <= hi:
        raise ValueError(f"{where}: median depth {median:.4g} m at depth scale {depth_scale:g} m per unit is "
                         f"implausible (expected {lo:g}-{hi:g} m); set the metres per unit of the depth file with "
                         f"{DEPTH_SCALE_OPTIONS} (a float depth image in metres: 1)")


def check_focal_lengths(K: np.ndarray, shape: tuple[int, int], where: str) -> None:
    """fx and fy of a 3x3 camera matrix between 0.1 and 20 times the larger side of an (H, W) image,
    in pixels: normalised intrinsics (fx about 1) are refused, not used as pixels."""
    H, W = shape
    fx, fy = K[0, 0], K[1, 1]
    lo, hi = (f * max(H, W) for f in PLAUSIBLE_FOCAL_SIDES)
    if not (lo <= fx <= hi and lo <= fy <= hi):
        raise ValueError(f"{where}: focal lengths fx={fx:g}, fy={fy:g} are implausible for a {W}x{H} image "
                         f"(expected {lo:g}-{hi:g} pixels; normalised intrinsics must be multiplied by the image size)")


def transposed_hint(K: np.ndarray) -> str:
    """"; transposed? ..." for a finite 3x3 `K` whose transpose is a camera matrix [[fx, s, cx], [0, fy,
    cy], [0, 0, 1]] (MATLAB's `IntrinsicMatrix` is K transposed), else ""."""
    T = np.asarray(K, dtype=np.float64).T
    if T.shape == (3, 3) and np.allclose(T[2], (0.0, 0.0, 1.0), atol=1e-6) and abs(T[1, 0]) <= 1e-6 and T[0, 2] != 0:
        return "; it is a camera matrix transposed (as MATLAB's IntrinsicMatrix is): use K.T"
    return ""


def check_intrinsics_for_image(K: np.ndarray, shape: tuple[int, int], where: str) -> np.ndarray:
    """A 3x3 pinhole matrix in pixels plausible for an (H, W) image: finite, last row [0, 0, 1],
    fx and fy between 0.1 and 20 times the larger side, principal point inside the image."""
    K = np.asarray(K, dtype=np.float64)
    H, W = shape
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise ValueError(f"{where}: expected a finite 3x3 camera matrix")
    if abs(K[2, 2] - 1.0) > 1e-6 or abs(K[2, 0]) > 1e-6 or abs(K[2, 1]) > 1e-6 or abs(K[1, 0]) > 1e-6:
        raise ValueError(f"{where}: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got rows {K[1:].tolist()}"
                         f"{transposed_hint(K)}")
    check_focal_lengths(K, shape, where)
    check_principal_point(K, shape, where)
    return K


def check_principal_point(K: np.ndarray, shape: tuple[int, int], where: str, strict: bool = True) -> None:
    """The principal point (cx, cy) of a 3x3 camera matrix for an (H, W) image. `strict` (the readers:
    whole images): it must lie on the image, else ValueError naming `where`. Otherwise (`RGBDFrame`,
    which may hold a crop, whose shifted K can put it anywhere) a point farther than
    `MAX_CENTRE_OFFSET` of the image size from its centre is warned of: the signature of intrinsics
    calibrated at another resolution (a 1280x960 K on a 640x480 frame puts it at the bottom-right
    corner, a 320x240 K at a quarter of the image), which sizes and shapes every geodesic patch
    wrongly without a word. So is a point at the centre of the image transposed (`MIN_TRANSPOSED_OFFSET`,
    `TRANSPOSED_CENTRE_OFFSET`): a 640x480 camera's image and depth given as (W, H) arrays put it 17 % of
    the width from the centre, which the 20 % let through, and were described mirrored with a K that
    does not fit them; so did a K with cx and cy swapped."""
    H, W = shape
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if strict:
        if not (0 <= cx <= W and 0 <= cy <= H):
            raise ValueError(f"{where}: principal point ({cx:g}, {cy:g}) lies outside the {W}x{H} image; are the "
                             "intrinsics for another image size? (scale fx, fy, cx, cy with the image)")
        return
    if (_centre_offset(cx, cy, (H, W)) >= MIN_TRANSPOSED_OFFSET
            and _centre_offset(cx, cy, (W, H)) <= TRANSPOSED_CENTRE_OFFSET):
        warnings.warn(f"{where}: principal point ({cx:g}, {cy:g}) lies at the centre of a {H}x{W} image, not of this "
                      f"{W}x{H} one: are the image and depth transposed ((W, H) arrays, as a column-major reader "
                      "gives), or cx and cy swapped in K? Pass the arrays as (H, W) (`frame.rotated90` turns a frame "
                      "with its K), and K as [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]", UserWarning, stacklevel=3)
    elif _centre_offset(cx, cy, (H, W)) > MAX_CENTRE_OFFSET:
        warnings.warn(f"{where}: principal point ({cx:g}, {cy:g}) lies far from the centre of the {W}x{H} image "
                      f"(expected within {MAX_CENTRE_OFFSET:.0%} of its size); are the intrinsics for another image "
                      "size? Scale fx, fy, cx, cy with the image (a crop's shifted K may be off-centre: then ignore "
                      "this)", UserWarning, stacklevel=3)


def _centre_offset(cx: float, cy: float, shape: tuple[int, int]) -> float:
    """How far the point (cx, cy), pixels, lies from the centre of an image of `shape` (H, W): the larger of
    its x offset over W and its y offset over H."""
    H, W = shape
    return max(abs(cx - (W - 1) / 2) / W, abs(cy - (H - 1) / 2) / H)


def unmask_depth(depth: Any) -> Any:
    """A depth map with the masked pixels of a numpy masked array as 0 (missing depth), not as the
    values stored under the mask (a sensor's no-data code, or NaN from `np.ma.masked_invalid`),
    which `np.asarray` would keep; anything else is returned as it is."""
    return depth.filled(0) if isinstance(depth, np.ma.MaskedArray) else depth


def check_not_8bit_depth(depth: np.ndarray, what: str = "depth") -> None:
    """ValueError naming `what` for an 8-bit integer depth map: no depth in metres is stored in whole
    metres, but a 16-bit depth PNG read as 8 bits (`cv2.imread(path, cv2.IMREAD_GRAYSCALE)`, PIL's
    `convert("L")`) is: its high byte, 2-4 for a scene at 0.5-1.1 m, which passed as metres."""
    if depth.dtype.kind in "iu" and depth.dtype.itemsize == 1:
        raise ValueError(f"{what}: 8-bit values ({depth.dtype}) are no depth in metres; a 16-bit depth PNG read as 8 "
                         "bits (cv2.IMREAD_GRAYSCALE, PIL's convert('L')) keeps only its high byte: read it with "
                         "geofeat.read_depth(path, depth_scale), which gives metres")


def as_points(xy: Any, what: str = "xy") -> np.ndarray:
    """An (N, 2) array of (x, y) pixels as float64 (an empty one as (0, 2)); NaN rows are kept for the
    caller to read as unknown. Any other shape is a ValueError naming `what`: reshaping a (2, N) array
    of x's then y's, or an (N, 3) one, would pair the wrong coordinates without a word."""
    if isinstance(xy, (str, bytes, dict)) or xy is None:
        raise TypeError(f"{what}: expected an (N, 2) array of (x, y) pixels, got {type(xy).__name__}")
    try:
        points = np.asarray(xy, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{what}: expected an (N, 2) array of (x, y) pixels, got {type(xy).__name__}") from error
    if points.size == 0 and points.ndim <= 2 and (points.ndim < 2 or points.shape[-1] in (0, 2)):
        return points.reshape(0, 2)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"{what}: expected shape (N, 2) of (x, y) pixels, got {points.shape}")
    return points


def check_landmarks(ids: np.ndarray, xy: np.ndarray, visible: np.ndarray, shape: tuple[int, int],
                    where: str) -> None:
    """The one landmark validator (groundtruth, match, bench): ids (N,) unique, visible landmarks of
    xy (N, 2) finite and on the (H, W) image (pixels, centres at integers, so within -0.5 .. W - 0.5),
    and not all within [0, 1] x [0, 1] (coordinates normalised by the image size: read as pixels they
    put every landmark in the top-left pixel, and a spline through them maps that pixel only)."""
    H, W = shape
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"landmarks: {where} repeats ids {uniq[counts > 1][:10].tolist()}")
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    bad = visible & ~np.isfinite(xy).all(axis=1)
    if bad.any():
        raise ValueError(f"landmarks: {where} has visible landmarks without finite coordinates: ids {ids[bad][:10].tolist()}")
    seen = xy[visible]
    if len(seen) >= 2 and min(H, W) > 2 and (seen >= 0).all() and (seen <= 1).all():
        raise ValueError(f"landmarks: {where} has all {len(seen)} visible landmarks within one pixel of the top-left "
                         f"corner (x, y in 0..1, e.g. {np.round(seen[0], 3).tolist()}); coordinates normalised by the "
                         f"image size? geofeat reads pixels: multiply x by {W} and y by {H}")
    off = visible & ((xy[:, 0] > W - 0.5) | (xy[:, 1] > H - 0.5) | (xy[:, 0] < -0.5) | (xy[:, 1] < -0.5))
    if off.any():
        raise ValueError(f"landmarks: {where} has visible landmarks off the {W}x{H} image: ids "
                         f"{ids[off][:10].tolist()} at {np.round(xy[off][:3], 1).tolist()}")


def is_reference_name(name: str) -> bool:
    """True when a frame name holds `master`, `ref` or `reference` (optionally with digits) as a whole
    token, tokens being split on `_`, `-`, `.` and spaces: `cloud_ref`, `frame-000-master`; not
    `cloth_preflight`."""
    return any(REFERENCE_TOKEN.match(token) for token in re.split(r"[_\-.\s]+", name.lower()))


def check_unique_names(folders: list[Path], what: str = "datasets") -> None:
    """Results are keyed by the sequence folder's name: refuse two different folders with one name."""
    seen: dict[str, Path] = {}
    for folder in folders:
        other = seen.setdefault(folder.name, folder)
        if other != folder:
            raise ValueError(f"{what}: two sequences are named {folder.name!r} ({other} and {folder}); results are "
                             "keyed by the sequence folder name, so rename one or run them separately")


def check_tps_dir(tps_dir: str | None) -> None:
    """`--tps-dir` (the authors' TPS ground truth), when given, must name an existing folder."""
    if tps_dir is not None and not Path(tps_dir).is_dir():
        raise ValueError(f"tps-dir: not a directory: {tps_dir}")
