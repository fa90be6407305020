"""Keypoint detection: OpenCV SIFT on the frame's gray image, strongest first."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from .constants import N_KEYPOINTS
from .frame import RGBDFrame
from .inputs import as_points, check_non_negative, check_whole

__all__ = ["DEFAULT_DETECTOR", "DETECTORS", "KEYPOINT_SETS", "Keypoints", "as_keypoints", "check_detector_name", "detect", "detect_sift"]

#: SIFT contrast threshold used by `detect` (OpenCV's default is 0.04; lower finds more keypoints).
DEFAULT_CONTRAST_THRESHOLD = 0.004
#: Keypoint sets of `detect`: "protocol" = OpenCV SIFT's n strongest exactly as OpenCV returns them
#: (the published matching-score protocol); "unique" = one keypoint per position, on depth.
KEYPOINT_SETS = ("protocol", "unique")
#: Detector names of `detect`: "sift" (OpenCV) and "geokey" (learned, `geofeat.detectors.geokey`);
#: "geokey=PATH" uses weights made by `geofeat train-detector`.
DETECTORS = ("sift", "geokey")
#: The detector of `detect` when none is named: GeoKey, which scores above SIFT with both geodesic
#: descriptors on every held-out simulated test set measured (`mild`, `paper`, `hard`, at 1024 and
#: 2048 keypoints; BENCHMARKS.md, "GeoKey v3.3"). `geofeat.extract` and `geofeat extract|match|track|
#: retrieval` use it for the geodesic descriptors and SIFT for the others, which need SIFT's orientation
#: (`detector_for`). The benchmark (`geofeat bench`) keeps SIFT, the published protocol's detector.
DEFAULT_DETECTOR = "geokey"
#: Options of `detect` that only GeoKey takes.
GEOKEY_OPTIONS = ("threshold", "min_fraction", "denoise")


@dataclass(eq=False)
class Keypoints:
    """Detected keypoints.

    Attributes:
        xy: (N, 2) float64 pixel coordinates (x, y), OpenCV convention.
        angles: (N,) float64 SIFT orientation, degrees as OpenCV reports it (clockwise on screen,
            in [0, 360)).
        sizes: (N,) float64 keypoint diameter, pixels.
        responses: (N,) float64 detector response, non-increasing.
    """

    xy: np.ndarray
    angles: np.ndarray
    sizes: np.ndarray
    responses: np.ndarray

    def __post_init__(self) -> None:
        """Fields as float64 arrays: xy (N, 2), the others (N,); ValueError naming the field otherwise
        (a field of another length would pair keypoints with another keypoint's angle or size)."""
        xy = np.asarray(self.xy, dtype=np.float64)
        if xy.size == 0 and xy.ndim <= 2:
            xy = xy.reshape(0, 2)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"xy: expected shape (N, 2) of (x, y) pixels, got {xy.shape}")
        self.xy = xy
        for name in ("angles", "sizes", "responses"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (len(xy),):
                raise ValueError(f"{name}: expected shape ({len(xy)},) like xy, got {value.shape}")
            setattr(self, name, value)

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    @property
    def scores(self) -> np.ndarray | None:
        """(N,) the detector's responses as scores (higher = better) for `Features.scores`; None when
        they are unknown (keypoints given as bare pixels have NaN responses)."""
        return self.responses if np.isfinite(self.responses).all() else None

    def __eq__(self, other) -> bool:
        """Equal xy, angles, sizes and responses (`geofeat.features.fields_equal`: NaN equals NaN)."""
        if not isinstance(other, Keypoints):
            return NotImplemented
        from .features import fields_equal

        return fields_equal(self, other, ("xy", "angles", "sizes", "responses"))

    __hash__ = None

    def __repr__(self) -> str:  # the dataclass's printed every array in full
        if not len(self):
            return "Keypoints(0 keypoints)"
        sizes = self.sizes[np.isfinite(self.sizes)]
        span = f", sizes {sizes.min():.3g}-{sizes.max():.3g} px" if sizes.size else ""
        return f"Keypoints({len(self)} keypoints{span})"

    def __getitem__(self, index) -> "Keypoints":
        """The keypoints at `index` (a slice, a boolean mask of one entry per keypoint, or an index
        array); an integer gives a set of one. A single bool or a tuple (numpy would add an axis, or
        index the (N, 2) positions' second axis) is a TypeError."""
        if isinstance(index, (bool, np.bool_, tuple)):
            raise TypeError(f"Keypoints: index with an integer, a slice, a boolean mask or an integer array, not "
                            f"{index!r}")
        if isinstance(index, (int, np.integer)):
            index = [index]
        elif not isinstance(index, slice):
            index = np.asarray(index)
            if index.ndim != 1 or (index.size and index.dtype.kind not in "biu"):
                raise TypeError(f"Keypoints: index with a 1-D boolean mask or integer array, got a {index.ndim}-D "
                                f"{index.dtype} array")
            if index.size == 0:
                index = index.astype(np.int64)
        return Keypoints(self.xy[index], self.angles[index], self.sizes[index], self.responses[index])

    def to_cv(self) -> list[cv2.KeyPoint]:
        """The keypoints as a list of cv2.KeyPoint (pt, size, angle, response)."""
        return [
            cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r))
            for (x, y), s, a, r in zip(self.xy, self.sizes, self.angles, self.responses)
        ]

    @classmethod
    def from_cv(cls, keypoints: list[cv2.KeyPoint]) -> "Keypoints":
        """Build from a list of cv2.KeyPoint (order kept)."""
        n = len(keypoints)
        xy = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(n, 2)
        return cls(
            xy,
            np.array([k.angle for k in keypoints], dtype=np.float64),
            np.array([k.size for k in keypoints], dtype=np.float64),
            np.array([k.response for k in keypoints], dtype=np.float64),
        )


def as_keypoints(keypoints, shape: tuple[int, int] | None = None, allow_empty: bool = False,
                 what: str = "keypoints") -> Keypoints:
    """The one keypoint normaliser that every stage calls.

    Args:
        keypoints: a `Keypoints`, a list/tuple of cv2.KeyPoint, or an (N, 2) array-like of (x, y)
            pixels. Arrays carry no orientation or size: they get angle 0 (image +x) and size NaN
            (unknown; descriptors that need a size use their documented default).
        shape: (H, W) of the image; when given, keypoints off the image raise ValueError.
        allow_empty: accept an empty set (else ValueError).
        what: the argument's name in error messages.

    Returns:
        `Keypoints` (a new object for arrays and cv2 lists; the same object for `Keypoints`).
    """
    if isinstance(keypoints, Keypoints):
        kps = keypoints
        n = np.shape(kps.xy)[0] if np.ndim(kps.xy) else -1
        bad = [name for name in ("angles", "sizes", "responses") if np.shape(getattr(kps, name)) != (n,)]
        if bad:  # a field replaced after construction
            raise ValueError(f"{what}: {', '.join(bad)} must have one entry per keypoint ({n}), got shapes "
                             f"{[np.shape(getattr(kps, name)) for name in bad]}")
    elif isinstance(keypoints, (list, tuple)) and keypoints and all(isinstance(k, cv2.KeyPoint) for k in keypoints):
        kps = Keypoints.from_cv(list(keypoints))
    else:
        try:
            xy = as_points(keypoints, what)
        except TypeError as error:
            raise TypeError(f"{what}: expected an (N, 2) array of (x, y) pixels, cv2.KeyPoints or Keypoints, "
                            f"got {type(keypoints).__name__}") from error
        n = len(xy)
        kps = Keypoints(xy, np.zeros(n), np.full(n, np.nan), np.full(n, np.nan))
    if len(kps) == 0 and not allow_empty:
        raise ValueError(f"{what}: the keypoint set is empty")
    xy = kps.xy
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"{what}: expected xy of shape (N, 2), got {xy.shape}")
    if not np.isfinite(xy).all():
        raise ValueError(f"{what}: contain NaN or infinite coordinates")
    if shape is not None and len(xy):
        H, W = shape
        off = (xy[:, 0] < -0.5) | (xy[:, 0] > W - 0.5) | (xy[:, 1] < -0.5) | (xy[:, 1] > H - 0.5)
        if off.any():
            i = int(np.argmax(off))
            swapped = not ((xy[:, 1] < -0.5) | (xy[:, 1] > W - 0.5) | (xy[:, 0] < -0.5) | (xy[:, 0] > H - 0.5)).any()
            hint = ("; all of them lie on the image as (row, column) pairs, as np.argwhere and scikit-image give "
                    "them: pass xy[:, ::-1] for (x, y)") if swapped else ""
            raise ValueError(f"{what}: {int(off.sum())} keypoint(s) off the {W}x{H} image, e.g. #{i} at "
                             f"({xy[i, 0]:.1f}, {xy[i, 1]:.1f}){hint}")
    return kps


def to_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W) float image in [0, 1] -> uint8 (rounded, clipped)."""
    return np.clip(np.rint(np.asarray(image, dtype=np.float32) * 255.0), 0, 255).astype(np.uint8)


def _check_n(n, zero_is_all: bool = False) -> int:
    """n >= 1 (or None = all, returned as 0; with `zero_is_all`, 0 too); anything else is a ValueError
    naming `n`."""
    if n is None:
        return 0
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < (0 if zero_is_all else 1):
        raise ValueError(f"n: expected a positive whole number of keypoints, an int (or {'0 or ' if zero_is_all else ''}"
                         f"None for all), got {n!r}")
    return int(n)


def check_detector_name(detector: str) -> str:
    """Validate a detector name ("sift", "geokey", "geokey=WEIGHTS"; the name in any case, "SIFT",
    "GeoKey=W.pt"); a weights file must be GeoKey weights (`load_geokey`, which keeps them for the
    detection), so that a missing, corrupt or wrong file fails before any work. Returns the
    canonical name, lower-case with the weights path as given ("geokey=W.pt"), which is what
    results record."""
    if not isinstance(detector, str):
        raise TypeError(f"detector: expected a name such as 'sift' or 'geokey', got {type(detector).__name__}")
    name, _, weights = detector.partition("=")
    name = name.strip().lower()
    if name not in DETECTORS or (weights and name != "geokey") or ("=" in detector and not weights):
        raise ValueError(f"detector: expected one of {', '.join(DETECTORS)} or geokey=WEIGHTS, got {detector!r}")
    if weights:
        from .detectors.geokey import load_geokey

        load_geokey(weights)  # a ValueError naming the file when it is missing, a folder, or not GeoKey weights
        return f"{name}={weights}"
    return name


def resolve_keypoint_set(detector: str, keypoint_set: str | None, default: str = "unique") -> str:
    """The keypoint set a `detector` ("sift", "geokey", "geokey=WEIGHTS") gives: `keypoint_set`, or
    when None `default` for SIFT and "unique" for GeoKey, whose keypoints are one per position by
    construction. ValueError for a set that is not in KEYPOINT_SETS, or that chooses among SIFT's
    keypoints ("protocol") with another detector."""
    sift = detector.partition("=")[0] == "sift"
    chosen = keypoint_set if keypoint_set is not None else (default if sift else "unique")
    if chosen not in KEYPOINT_SETS:
        raise ValueError(f"keypoint_set: expected one of {', '.join(KEYPOINT_SETS)}, got {chosen!r}")
    if not sift and chosen != "unique":
        raise ValueError(f"keypoint_set: {chosen!r} chooses among SIFT's keypoints; {detector}'s are one per "
                         "position ('unique'): leave it out, or use detector='sift'")
    return chosen


def detector_for(descriptor: str, detector: str | None = None) -> str:
    """The detector that goes with `descriptor`: `detector` when named; else `DEFAULT_DETECTOR`
    (GeoKey) for a geodesic descriptor (GeoPatch, GeoBit: rotation-invariant, sized from depth) and
    SIFT for the others, which take their orientation and scale from SIFT's keypoints."""
    from .descriptors import GEODESIC_DESCRIPTORS

    if detector is not None:  # "" is checked (and refused) like any other name
        return detector
    base = str(descriptor).strip().partition("=")[0].lower()  # as `check_descriptor_name` reads it
    return DEFAULT_DETECTOR if base in GEODESIC_DESCRIPTORS else "sift"


def group_by_detector(descriptors, detector: str | None = None) -> dict[str, tuple[str, ...]]:
    """{detector: the descriptors described on its keypoints}, each descriptor with
    `detector_for(descriptor, detector)`, in the order given: descriptors of one group share one
    detection (and the geodesic ones one mesh and one set of polar patches). Each detector is checked
    (`check_detector_name`) before any work."""
    groups: dict[str, tuple[str, ...]] = {}
    for name in descriptors:
        det = check_detector_name(detector_for(name, detector))
        groups[det] = groups.get(det, ()) + (name,)
    return groups


def detect(frame: RGBDFrame, n: int | None = N_KEYPOINTS, detector: str = DEFAULT_DETECTOR, **options) -> Keypoints:
    """Detect keypoints on `frame`, best first.

    Args:
        frame: the RGB-D frame.
        n: maximum number of keypoints (>= 1), or None for all.
        detector: "sift" (OpenCV SIFT, `detect_sift`; the published protocol's keypoints), "geokey"
            (the learned deformation-aware detector with the shipped weights: corner candidates on
            pixels with depth, scored by image cues, plus depth cues when the weights use them;
            `geofeat.detectors.geokey`) or "geokey=WEIGHTS" (weights from `geofeat train-detector`).
        **options: options of `detect_sift` (keypoint_set, contrast_threshold, mask, ...); GeoKey
            takes `keypoint_set` only as "unique" (what its keypoints are), `mask`, `threshold`
            (its minimum logit; default the weights' own, chosen on validation; -inf returns the
            `n` best whatever their score), `min_fraction` (the best this fraction of the
            frame's candidates are kept whatever the threshold; default the weights' own) and
            `denoise` (the edge-preserving filter's range before detection, in noise levels; 0 =
            none; default the weights' own).

    Returns:
        `Keypoints` sorted best first; fewer than `n` when the detector's threshold stops it (SIFT's
        contrast threshold, GeoKey's score threshold); an empty set, with a warning, when the frame gives
        none (no texture, or no depth under it). GeoKey's have angle 0 and a size of 8 px per pyramid level.
    """
    if not isinstance(frame, RGBDFrame):
        raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
    detector = check_detector_name(detector)
    name, _, weights = detector.partition("=")
    if name == "sift":
        geokey_only = sorted(set(options) & set(GEOKEY_OPTIONS))
        if geokey_only:  # was "detect_sift() got an unexpected keyword argument 'threshold'"
            raise TypeError(f"detector: options {geokey_only} apply to 'geokey' only (SIFT's threshold is "
                            "contrast_threshold)")
        return detect_sift(frame, n, **options)
    n = _check_n(n)
    from .detectors.geokey import detect_geokey, load_geokey

    mask = options.pop("mask", None)
    threshold = options.pop("threshold", None)
    min_fraction = options.pop("min_fraction", None)
    denoise = options.pop("denoise", None)
    resolve_keypoint_set(name, options.pop("keypoint_set", None))  # only "unique" applies to GeoKey
    if options:
        raise TypeError(f"detector: options {sorted(options)} apply to 'sift' only")
    return detect_geokey(frame, n, load_geokey(weights or None), mask=mask, threshold=threshold,
                         min_fraction=min_fraction, denoise=denoise)


def check_mask(mask, shape: tuple[int, int]) -> np.ndarray:
    """A detection mask as an (H, W) bool array, True where keypoints are allowed (nonzero).
    ValueError naming `mask` for another shape, a non-numeric array, or NaN values: NaN is nonzero,
    so a float mask with NaN for "unknown" allowed those pixels without a word."""
    mask = np.asarray(mask)
    if mask.shape != tuple(shape):
        raise ValueError(f"mask: expected shape {tuple(shape)}, got {mask.shape}")
    if mask.dtype.kind not in "biuf":
        raise ValueError(f"mask: expected a bool or numeric array (nonzero = allowed), got dtype {mask.dtype}")
    if mask.dtype.kind == "f" and np.isnan(mask).any():
        raise ValueError("mask: contains NaN; use 0 where keypoints are not allowed and nonzero where they are")
    return mask != 0


def detect_sift(
    frame: RGBDFrame,
    n: int = N_KEYPOINTS,
    contrast_threshold: float = DEFAULT_CONTRAST_THRESHOLD,
    require_depth: bool = True,
    border_px: int = 3,
    mask: np.ndarray | None = None,
    keypoint_set: str = "unique",
) -> Keypoints:
    """Detect SIFT keypoints on `frame.image`, strongest `n` first.

    Args:
        frame: the RGB-D frame (its gray image is converted to uint8 for OpenCV).
        n: maximum number of keypoints kept (by decreasing response, after filtering); None = all.
        contrast_threshold: SIFT contrast threshold (OpenCV `contrastThreshold`).
        require_depth: drop keypoints whose rounded pixel has no depth (`frame.depth == 0`).
        border_px: drop keypoints closer than this to the image border, pixels (a whole number >= 0).
        mask: optional (H, W) uint8/bool detection mask (nonzero = allowed).
        keypoint_set: "unique" keeps only the strongest of keypoints at the same position (SIFT
            repeats a position once per dominant orientation; position-only descriptors would
            describe it twice), after the depth and border filters. "protocol" is the published
            matching-score protocol's set: `cv2.SIFT_create(nfeatures=n, contrastThreshold=...)`,
            the n strongest exactly as OpenCV returns them (a position with two orientations is two
            keypoints), with no depth or border filter (`require_depth`, `border_px` are ignored;
            the benchmark drops keypoints off the object afterwards, as the protocol does).

    Returns:
        `Keypoints` sorted by decreasing response (ties keep OpenCV's order).
    """
    if not isinstance(frame, RGBDFrame):
        raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
    n = _check_n(n)
    check_non_negative(contrast_threshold, "contrast_threshold")
    border_px = check_whole(border_px, "border_px", minimum=0)
    H, W = frame.shape
    if mask is not None:
        mask = check_mask(mask, (H, W)).astype(np.uint8)
    if keypoint_set not in KEYPOINT_SETS:
        raise ValueError(f"keypoint_set: expected one of {', '.join(KEYPOINT_SETS)}, got {keypoint_set!r}")
    where = "in this frame" if mask is None else "inside the mask"
    if keypoint_set == "protocol":
        # OpenCV takes a C int: a larger budget keeps every keypoint, as the frame has far fewer
        sift = cv2.SIFT_create(nfeatures=min(int(n or 0), np.iinfo(np.int32).max),
                               contrastThreshold=float(contrast_threshold))
        kps = Keypoints.from_cv(list(sift.detect(to_uint8(frame.image), mask)))
        order = np.argsort(-kps.responses, kind="stable")
        return _warn_if_none(kps[order[:n] if n else order], f"no keypoint {where} (no texture)")
    sift = cv2.SIFT_create(contrastThreshold=float(contrast_threshold))
    kps = Keypoints.from_cv(list(sift.detect(to_uint8(frame.image), mask)))
    if len(kps) == 0:
        return _warn_if_none(kps, f"no keypoint {where} (no texture)")
    x, y = kps.xy[:, 0], kps.xy[:, 1]
    keep = (x >= border_px) & (x <= W - 1 - border_px) & (y >= border_px) & (y <= H - 1 - border_px)
    if require_depth:
        xi = np.clip(np.rint(x).astype(np.int64), 0, W - 1)
        yi = np.clip(np.rint(y).astype(np.int64), 0, H - 1)
        keep &= frame.depth[yi, xi] > 0
    kps = kps[keep]
    order = np.argsort(-kps.responses, kind="stable")
    if len(order):
        _, first = np.unique(np.round(kps.xy[order], 2), axis=0, return_index=True)
        order = order[np.sort(first)]
    if n:
        order = order[:n]
    return _warn_if_none(kps[order], f"no keypoint with depth under it {where} (no texture or no depth)")


def _warn_if_none(kps: Keypoints, why: str) -> Keypoints:
    """`kps`, with a warning when it is empty, as GeoKey warns: an empty set, matched or described,
    gives empty results that look like a bad descriptor rather than a blank or black frame."""
    if len(kps) == 0:
        warnings.warn(f"sift: {why}", UserWarning, stacklevel=5)  # the caller of `detect`
    return kps
