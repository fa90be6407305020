"""Options shared by several commands (descriptor and detector names, depth profile, the
sequence-and-frames options of extract/match, the options of the applications)."""

from __future__ import annotations

import argparse
import math

from ..constants import DEPTH_PROFILE_NAMES, DEPTH_SCALE_M, N_KEYPOINTS
from ..descriptors import available_descriptors, check_descriptor_name
from ..inputs import check_depth_scale, check_radius
from ..keypoints import DEFAULT_DETECTOR, KEYPOINT_SETS, check_detector_name, detector_for, resolve_keypoint_set


def descriptor_name(text: str) -> str:
    """argparse type: a checked descriptor name (a usage error, exit 2, for an unknown one)."""
    try:
        return check_descriptor_name(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def keypoint_count(text: str) -> int:
    """argparse type: a positive number of keypoints per frame (a usage error, exit 2, otherwise)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number of keypoints per frame, got {text!r}")
    return value


# argparse types for the numeric options: a bad value is a usage error that names the flag
# ("argument --words: expected a whole number >= 2, got '1'", exit 2) before any work, rather than a
# later error naming the Python parameter behind it.

def whole_number(minimum: int, maximum: int | None = None):
    """argparse type: a whole number >= `minimum` (and <= `maximum` when given)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum or (maximum is not None and value > maximum):
            bound = f">= {minimum}" if maximum is None else f"from {minimum} to {maximum}"
            raise argparse.ArgumentTypeError(f"expected a whole number {bound}, got {text!r}")
        return value
    return parse


def _finite(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def finite_number(text: str) -> float:
    """argparse type: a finite number (not nan, not inf)."""
    value = _finite(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def number_at_least(minimum: float):
    """argparse type: a finite number >= `minimum`."""
    def parse(text: str) -> float:
        value = _finite(text)
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected a number >= {minimum:g}, got {text!r}")
        return value
    return parse


def positive_number(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = _finite(text)
    if value is None or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def number_between(lo: float, hi: float):
    """argparse type: a finite number strictly between `lo` and `hi`."""
    def parse(text: str) -> float:
        value = _finite(text)
        if value is None or not lo < value < hi:
            raise argparse.ArgumentTypeError(f"expected a number strictly between {lo:g} and {hi:g}, got {text!r}")
        return value
    return parse


def _checked(text: str, check, flag: str) -> float:
    """`check(value, flag)` of a positive number; its ValueError as a usage error without the flag
    (argparse names it)."""
    value = positive_number(text)
    try:
        return check(value, flag)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).removeprefix(f"{flag}: ")) from None


def radius_value(text: str) -> float:
    """argparse type: a plausible geodesic radius in metres (`geofeat.inputs.check_radius`)."""
    return _checked(text, check_radius, "--radius")


def depth_scale_value(text: str) -> float:
    """argparse type: a plausible depth scale, metres per depth-PNG unit (`geofeat.inputs.check_depth_scale`)."""
    return _checked(text, check_depth_scale, "--depth-scale")


def radius_option(p: argparse.ArgumentParser) -> None:
    """--radius (default: the sequence's geofeat.json or 0.075)."""
    p.add_argument("--radius", type=radius_value, default=None,
                   help="geodesic radius, metres (default: geofeat.json or 0.075)")


def depth_scale_option(p: argparse.ArgumentParser) -> None:
    """--depth-scale (default: the sequence's geofeat.json or 0.001)."""
    p.add_argument("--depth-scale", type=depth_scale_value, default=None,
                   help=f"metres per depth-PNG unit (default: geofeat.json or {DEPTH_SCALE_M})")


def depth_profile_option(p: argparse.ArgumentParser, default: str | None) -> None:
    """--depth-profile (auto, kinect, quantised, clean) with `default`: None for the commands that read
    sequences (each sequence's geofeat.json profile when it names one, else auto: see
    `depth.sequence_depth_profile`), so that an explicit "auto" measures even where geofeat.json
    names a profile; "auto" for `demo` (a frame without geofeat.json)."""
    what = ("default auto" if default == "auto" else
            "default: the sequence's geofeat.json profile when it names one, else auto; given explicitly, auto "
            "measures even where geofeat.json names a profile")
    p.add_argument("--depth-profile", choices=DEPTH_PROFILE_NAMES, default=default, type=str.lower,
                   help="depth preprocessing: kinect (hole filling, two rounds of smoothing, half-resolution "
                        "mesh; noisy depth), quantised (one round; noise-free depth in coarse steps such as "
                        "millimetre PNGs), clean (raw depth, holes filled, full-resolution mesh) or auto "
                        f"(chosen from the measured depth noise and steps); {what}")


def detector_name(text: str) -> str:
    """argparse type: a checked detector name."""
    try:
        return check_detector_name(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def detector_option(p: argparse.ArgumentParser, default: str | None = "sift") -> None:
    """--detector (sift, geokey, geokey=WEIGHTS). `bench` defaults to SIFT (the published protocol's
    detector); `extract`, `match`, `track` and `retrieval` to None, resolved by `detector_for` per
    descriptor."""
    what = default or (f"{DEFAULT_DETECTOR} for the geodesic descriptors, sift for the others "
                       "(they need SIFT's orientation)")
    p.add_argument("--detector", default=default, type=detector_name,
                   help=f"keypoint detector: sift (OpenCV), geokey (learned, image + depth cues) or "
                        f"geokey=WEIGHTS (from `geofeat train-detector`); default {what}")


def keypoint_set_for(detector: str, keypoint_set: str | None, default: str) -> str:
    """--keypoint-set checked against the detector: `keypoint_set`, else `default`. It chooses among
    SIFT's keypoints, so naming it with another detector (GeoKey has one keypoint per position) is an
    error rather than an option silently ignored. Other detectors' keypoints are "unique"."""
    if keypoint_set is not None and detector != "sift":
        raise ValueError(f"--keypoint-set: chooses among SIFT's keypoints, not {detector}'s (GeoKey has one "
                         "keypoint per position); leave it out, or add --detector sift")
    return resolve_keypoint_set(detector, keypoint_set, default)


def resolve_detection(args: argparse.Namespace) -> str:
    """Resolve `args.detector` for `args.descriptor` (`detector_for`) and `args.keypoint_set` for it
    (`keypoint_set_for`, default "unique"). Returns the detection's words for the command's first line."""
    args.detector = detector_for(args.descriptor, args.detector)
    args.keypoint_set = keypoint_set_for(args.detector, args.keypoint_set, "unique")
    if args.detector == "sift":
        return f"detector {args.detector}, keypoints {args.keypoint_set}"
    return f"detector {args.detector}"


def frames_options(p: argparse.ArgumentParser) -> None:
    """The options of `extract` and `match`: one sequence folder, one descriptor, detection and depth."""
    p.add_argument("folder", help="a sequence folder in the public layout (<name>-rgb.png, <name>-depth.png, intrinsics.xml)")
    p.add_argument("--descriptor", default="geobit", type=descriptor_name,
                   help=f"one of {', '.join(available_descriptors())}, or geopatch=WEIGHTS.pt (default geobit)")
    p.add_argument("--keypoints", type=keypoint_count, default=N_KEYPOINTS, help="keypoints per frame (default 2048)")
    detector_option(p, None)
    p.add_argument("--keypoint-set", choices=KEYPOINT_SETS, default=None,
                   help="SIFT keypoints only. unique: one keypoint per position (default); protocol: SIFT's "
                        "strongest as OpenCV returns them")
    depth_profile_option(p, None)
    radius_option(p)
    depth_scale_option(p)


def device_option(p: argparse.ArgumentParser, also: str = "", then: str = "") -> None:
    """--device (checked by `common.check_device`, or `common.check_devices` for several
    descriptors): cpu, or cuda / cuda:N for GeoPatch on the GPU; `also` names what else runs there
    (", and the matching,"), `then` is said after the rest ("; the other descriptors on the CPU")."""
    p.add_argument("--device", default="cpu",
                   help=f"cpu (default), or cuda / cuda:N: GeoPatch's walk, sampling and CNN{also} on the GPU "
                        f"(geofeat[cuda]; torch weights; descriptors within about 2e-4 of the CPU torch backend's){then}")


def app_options(p: argparse.ArgumentParser) -> None:
    """The options of `retrieval` and `track`: descriptors, output folder, detection (by default each
    descriptor on its own detector, `detector_for`), ground truth, depth."""
    p.add_argument("--descriptors", default="geopatch,geobit,sift",
                   help=f"comma-separated, from {','.join(available_descriptors())} (default geopatch,geobit,sift)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="replace what geofeat wrote in an existing non-empty OUT (other files stay)")
    p.add_argument("--keypoints", type=keypoint_count, default=N_KEYPOINTS, help="keypoints per frame (default 2048)")
    detector_option(p, None)
    p.add_argument("--tps-dir", default=None, help="the authors' TPS ground truth (objmask, warps), one folder per sequence")
    radius_option(p)
    depth_scale_option(p)


def names(text: str) -> tuple[str, ...]:
    """Comma-separated descriptor names ("geopatch,geobit") -> a tuple, empty entries dropped."""
    return tuple(d for d in text.split(",") if d)
