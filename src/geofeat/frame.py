"""RGBDFrame: one registered colour + depth image with its pinhole intrinsics."""

from __future__ import annotations

import math
import numbers
import warnings
from contextvars import ContextVar
from dataclasses import dataclass, field

import cv2
import numpy as np

from .constants import MAX_PLAUSIBLE_DEPTH_M, MIN_FRAME_SIDE_PX
from .inputs import (PLAUSIBLE_MEDIAN_DEPTH_M, USUAL_MEDIAN_DEPTH_M, DepthUnitsWarning, as_points, check_focal_lengths,
                     check_not_8bit_depth, check_principal_point, transposed_hint, unit_readings, unmask_depth)


def to_gray(image: np.ndarray, warn_dark: bool = True) -> np.ndarray:
    """Convert an (H, W) or (H, W, 3) BGR image (uint8, uint16 or float in [0, 1]) to float32 gray in [0, 1];
    a uint16 or float image that uses under 1/16 of its full scale warns (`_warn_if_dark`) unless
    `warn_dark` is False. Always a new array (not a view of `image`)."""
    image = np.asarray(image)
    if image.dtype.kind not in "biuf":
        raise TypeError(f"image: expected uint8, uint16 or float values in [0, 1], got dtype {image.dtype}")
    if not image.dtype.isnative:
        # big-endian 16-bit pixels (raw PNG bytes, FITS) are not `== np.uint16`: they were read as floats,
        # refused as ">u2 images must lie in [0, 1]", or taken as white when they held 0 and 1
        image = image.astype(image.dtype.newbyteorder("="))
    if image.size == 0:
        raise ValueError(f"image: empty, shape {image.shape}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        if image.dtype == np.uint8:
            gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
        elif image.dtype == np.uint16:
            gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32) / 65535.0
        else:
            gray = cv2.cvtColor(image.astype(np.float32), cv2.COLOR_BGR2GRAY)
    elif image.ndim == 2:
        gray = image.astype(np.float32)
        if image.dtype == np.uint8:
            gray /= 255.0
        elif image.dtype == np.uint16:
            gray /= 65535.0
    else:
        hint = ""
        if image.ndim == 3 and image.shape[0] in (1, 3, 4) and image.shape[2] > 4:  # a torch / CHW layout
            hint = "; channels first? transpose it to (H, W, C) (a torch tensor: image.permute(1, 2, 0))"
        elif image.ndim == 3 and image.shape[2] == 4:
            hint = "; drop the alpha channel (image[:, :, :3])"
        raise ValueError(f"image: expected shape (H, W) or (H, W, 3), got {image.shape}{hint}")
    if image.dtype != np.uint8 and image.dtype != np.uint16:  # those are finite and in [0, 1] by construction
        if not np.isfinite(gray).all():
            raise ValueError("image: contains NaN or infinite values")
        if gray.min() < 0 or gray.max() > 1.0 + 1e-6:
            raise ValueError(
                f"image: {image.dtype} images must lie in [0, 1], got range [{gray.min():.3g}, {gray.max():.3g}]"
                " (pass 0-255 images as uint8, or divide by 255)"
            )
    if warn_dark:
        _warn_if_dark(image, float(gray.max()))
    return np.ascontiguousarray(gray, dtype=np.float32)


def from_pil(image):
    """A PIL image as the array geofeat reads: colour as (H, W, 3) BGR (PIL holds RGB: read as BGR, its
    red and blue would swap in the gray image and the colour copy without a word), one-band modes
    (L, I;16, F) as (H, W); anything else is returned as it is."""
    if not all(hasattr(image, a) for a in ("getbands", "convert", "mode")):
        return image
    if len(image.getbands()) == 1:
        return np.asarray(image)
    return np.ascontiguousarray(np.asarray(image.convert("RGB"))[:, :, ::-1])  # RGBA, P, CMYK, ... -> RGB -> BGR


#: A uint16 or float image whose brightest pixel is below this fraction of its full scale is warned of.
DARK_IMAGE_FRACTION = 1.0 / 16.0


def _warn_if_dark(image: np.ndarray, brightest: float, where: str = "image", stacklevel: int = 4) -> None:
    """Warn of a uint16 or float image that uses under `DARK_IMAGE_FRACTION` of its full scale: 8-bit
    values in a uint16 array or PNG (or a Kinect's 10-bit IR) read as 0-65535, or floats divided by
    255 twice, give a nearly black gray image, on which SIFT finds nothing and patches hold no
    contrast. `brightest`: the image's brightest value as a fraction of its full scale; `where`
    begins the message (the argument, or the file)."""
    if image.dtype == np.uint8 or image.dtype.kind not in "uf":
        return
    if not 0.0 < brightest < DARK_IMAGE_FRACTION:
        return
    if image.dtype == np.uint16:
        hint = (f"its brightest value is {int(image.max())} of 65535: 8-bit values in a uint16 array? geofeat reads "
                "uint16 images as 0-65535: pass 8-bit values as uint8, or scale the image to the full range")
    else:
        hint = (f"its brightest value is {brightest:.3g}: float images are read as 0-1 (1 = white); divided by "
                "255 twice? scale the image to [0, 1]")
    warnings.warn(f"{where}: nearly black ({brightest:.1%} of the full {image.dtype} scale); {hint}", UserWarning,
                  stacklevel=stacklevel)


def check_intrinsics(K: np.ndarray) -> np.ndarray:
    """Validate a 3x3 pinhole camera matrix and return it as float64."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K: expected a (3, 3) camera matrix, got shape {K.shape}")
    if not np.isfinite(K).all():
        raise ValueError("K: contains NaN or infinite values")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    if abs(K[2, 2] - 1.0) > 1e-9 or abs(K[2, 0]) > 1e-9 or abs(K[2, 1]) > 1e-9:
        raise ValueError(f"K: last row must be [0, 0, 1], got {K[2].tolist()}{transposed_hint(K)}")
    if abs(K[1, 0]) > 1e-9:  # no projection in geofeat reads K[1, 0]: it would be ignored
        raise ValueError(f"K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got K[1, 0] = {K[1, 0]:g}")
    return K


def check_depth(depth: np.ndarray, shape: tuple[int, int] | None = None, warn_units: bool = False) -> np.ndarray:
    """Validate an (H, W) depth map in metres (0 = missing; so are the masked pixels of a masked
    array) and return it as float32. A median depth
    above `MAX_PLAUSIBLE_DEPTH_M` (millimetres) is a ValueError. With `warn_units`, one below the
    readers' smallest plausible median (`inputs.PLAUSIBLE_MEDIAN_DEPTH_M`, 5 cm) warns
    (`DepthUnitsWarning`): metres divided by 1000 again make every geodesic patch leave the surface;
    so does one beyond an RGB-D camera's range (`inputs.USUAL_MEDIAN_DEPTH_M`, 4.5 m): centimetres of
    a scene nearer than 50 cm, or decimetres, shrank every geodesic patch 100 or 10 times."""
    depth = np.asarray(unmask_depth(depth))
    if depth.ndim != 2:
        raise ValueError(f"depth: expected shape (H, W), got {depth.shape}")
    if shape is not None and depth.shape != shape:
        raise ValueError(f"depth: shape {depth.shape} differs from the image shape {shape}")
    if depth.dtype.kind not in "fiu":
        raise TypeError(f"depth: expected a numeric array in metres, got dtype {depth.dtype}")
    check_not_8bit_depth(depth)
    depth = depth.astype(np.float32)
    if not np.isfinite(depth).all():
        raise ValueError("depth: contains NaN or infinite values; use 0 for missing depth")
    lowest, highest = float(depth.min()), float(depth.max())
    if lowest < 0:
        raise ValueError(f"depth: negative values (min {lowest:.3g} m); use 0 for missing depth")
    if highest <= 0:
        raise ValueError("depth: every pixel is 0 (missing); nothing to build a surface from")
    # the unit check needs only the typical depth: the median of every 4th pixel along both axes
    # when that holds enough pixels with depth (a sixteenth of the work), else of all of them
    sample = depth[::4, ::4]
    sample = sample[sample > 0]
    median = float(np.median(sample if sample.size >= 1000 else depth[depth > 0]))
    if median > MAX_PLAUSIBLE_DEPTH_M:
        readings = unit_readings(median) or "no common unit makes it a plausible depth"
        raise ValueError(f"depth: median {median:.1f} is not in metres (at most {MAX_PLAUSIBLE_DEPTH_M:g} m expected); "
                         f"{readings}: convert it to metres (or read it with read_frame(..., "
                         "depth_scale=<metres per unit>))")
    nearest, farthest = PLAUSIBLE_MEDIAN_DEPTH_M[0], USUAL_MEDIAN_DEPTH_M[1]
    if warn_units and median < nearest:
        warnings.warn(f"depth: median {median:.3g} m is nearer than an RGB-D camera sees (expected at least "
                      f"{nearest:g} m); is it in metres (not metres divided by 1000 again)? Geodesic patches "
                      "of a few centimetres would leave the surface, and no keypoint would be described",
                      DepthUnitsWarning, stacklevel=3)
    elif warn_units and median > farthest:
        readings = unit_readings(median, USUAL_MEDIAN_DEPTH_M, skip=1.0)
        warnings.warn(f"depth: median {median:.3g} m is farther than an RGB-D camera sees (expected at most "
                      f"{farthest:g} m); is it in metres (not centimetres or decimetres)? Geodesic patches of a few "
                      f"centimetres would shrink to a few pixels{f'; {readings}' if readings else ''}: unless the "
                      "scene really is that far, convert the depth to metres", DepthUnitsWarning, stacklevel=3)
    return np.ascontiguousarray(depth)


#: True while a reader (`RGBDFrame._from_reader`) makes a frame: its depth units are warned of by the reader.
_READER_CHECKED_UNITS: ContextVar[bool] = ContextVar("geofeat_reader_checked_units", default=False)


@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """A registered RGB-D frame.

    Attributes:
        image: (H, W) float32 gray image in [0, 1].
        depth: (H, W) float32 depth in metres, 0 where missing (and where a masked array is masked):
            a median above 50 m (millimetres)
            raises ValueError, one below 5 cm (metres divided by 1000 again?) or above 4.5 m
            (centimetres, decimetres?) warns.
        K: (3, 3) float64 pinhole intrinsics in pixels (OpenCV convention: the centre of the
            top-left pixel is (0, 0)), for this image's resolution: focal lengths implausible for
            the image size raise ValueError, a principal point far from the image centre (or off
            it: intrinsics of another resolution?) warns.
        color: optional (H, W, 3) uint8 BGR image, kept for display: a copy of the one given, or of a
            uint16 one's high bytes, or of a float one times 255 (`display_colour`); None for gray.

    `image` may also be a PIL image: its RGB is turned into BGR (`from_pil`).

    A frame is immutable: its arrays are its own read-only copies (`read_only`), so an edit in place
    (`frame.depth[...] = ...`) raises numpy's "assignment destination is read-only" and an edit of the
    caller's arrays does not reach the frame; what is cached on the frame (its mesh, `frame_mesh`; the
    depth profile "auto" picks) stays the frame's. `with_image` makes a frame with another image,
    `RGBDFrame(image, new_depth, frame.K)` one with another depth.
    """

    image: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    color: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __init__(self, image: np.ndarray, depth: np.ndarray, K: np.ndarray) -> None:
        image = np.asarray(from_pil(image))
        if image.ndim not in (2, 3):
            raise ValueError(f"image: expected shape (H, W) or (H, W, 3), got {image.shape}")
        gray = to_gray(image)
        # the frame's own copy, as for the depth and K: the caller may draw on its array afterwards
        # (H, W, 3) only: an (H, W, 1) image is gray, shown (`geofeat.viz.to_bgr`) from `image` as an (H, W) one
        color = display_colour(image)
        # `to_gray` and `check_depth` return new arrays: the frame's own, as the copies of K and the colour
        depth = check_depth(depth, gray.shape, warn_units=not _READER_CHECKED_UNITS.get())
        K = check_intrinsics(K).copy()  # the frame's own copy, as for the depth: not the caller's array
        check_focal_lengths(K, gray.shape, "K")
        check_principal_point(K, gray.shape, "K", strict=False)
        for name, value in (("image", gray), ("depth", depth), ("K", K), ("color", color)):
            object.__setattr__(self, name, read_only(value))

    @classmethod
    def _from_reader(cls, image: np.ndarray, depth: np.ndarray, K: np.ndarray) -> "RGBDFrame":
        """`RGBDFrame(image, depth, K)` without its depth-units warnings (`check_depth`): the readers
        (`geofeat.io`) check the depth against their depth scale and warn of it once per sequence
        (`inputs.warn_depth_units`), not once for each frame."""
        token = _READER_CHECKED_UNITS.set(True)
        try:
            return cls(image, depth, K)
        finally:
            _READER_CHECKED_UNITS.reset(token)

    def __eq__(self, other) -> bool:
        """Frames with equal gray images, depth and intrinsics (the colour image, kept for display, is
        not compared). The dataclass's own `==` compared the arrays as a tuple: "The truth value of an
        array with more than one element is ambiguous" for any two distinct frames (also from
        `frames.index(frame)` or `frame in frames`)."""
        if not isinstance(other, RGBDFrame):
            return NotImplemented
        from .features import fields_equal

        return self is other or fields_equal(self, other, ("image", "depth", "K"))

    __hash__ = None  # equal by value over mutable arrays: not hashable ("unhashable type: 'RGBDFrame'")

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return self.image.shape  # type: ignore[return-value]

    def __repr__(self) -> str:  # the dataclass's printed every array in full
        H, W = self.shape
        valid = self.depth > 0
        depth = (f"depth {float(self.depth[valid].min()):.3g}-{float(self.depth[valid].max()):.3g} m, "
                 f"{valid.mean():.0%} valid" if valid.any() else "no depth")
        colour = "colour, " if self.color is not None else ""
        return f"RGBDFrame({W}x{H}, {colour}{depth}, fx {self.K[0, 0]:.1f} fy {self.K[1, 1]:.1f} px)"

    def with_image(self, image: np.ndarray) -> "RGBDFrame":
        """This frame's depth and intrinsics (checked already, and shared, not copied) with another
        (H, W) gray image of the same shape, e.g. a filtered copy for a detector. The image is read
        as the constructor reads it (uint8 0-255, uint16 0-65535, float in [0, 1]; NaN or values
        outside that range raise ValueError) into the frame's own float32 copy. The colour image is
        kept for display."""
        image = np.asarray(image)
        if image.shape != self.shape:
            raise ValueError(f"image: expected shape {self.shape}, got {image.shape}")
        # as the constructor reads it: a uint8 image was kept as floats 0-255 (read as [0, 1] by every
        # stage: SIFT found nothing on it), NaN and 0-255 floats were taken, the caller's array was shared;
        # no dark-image warning here: the frame's constructor gave it for its own image
        image = read_only(to_gray(image, warn_dark=False))  # a new array, the frame's own
        frame = object.__new__(RGBDFrame)
        for name, value in (("image", image), ("depth", self.depth), ("K", self.K), ("color", self.color)):
            object.__setattr__(frame, name, value)
        return frame

    def rotated90(self, k: int = 1) -> "RGBDFrame":
        """The same frame seen by a camera rolled by k * 90 degrees (image rotated counter-clockwise
        as displayed), with intrinsics changed consistently. Used to test rotation invariance.
        k: an integer number of quarter turns (any sign). The gray image is this frame's own,
        turned (also when it is not its colour image's gray, as after `with_image`); the colour
        image is turned with it. Keypoints move as `rotate_points90` says; an OpenCV angle
        (clockwise as displayed) becomes angle - 90 k degrees."""
        k = quarter_turns(k)
        H, W = self.shape
        K = self.K.copy()
        image = self.color if self.color is not None else self.image
        fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
        if k == 0:
            return RGBDFrame(image, self.depth, K).with_image(self.image.copy())
        if k in (1, 3) and abs(s) > 1e-9:  # the skew would land in K[1, 0], which no camera matrix here has
            raise ValueError(f"K: rotated90 by an odd number of quarter turns needs no skew, got K[0, 1] = {s:g}")
        if k == 1:  # new (x', y') = (y, W - 1 - x)
            Kn = np.array([[fy, 0, cy], [0, fx, W - 1 - cx], [0, 0, 1.0]])
        elif k == 2:  # new (x', y') = (W - 1 - x, H - 1 - y); the skew is kept
            Kn = np.array([[fx, s, W - 1 - cx], [0, fy, H - 1 - cy], [0, 0, 1.0]])
        else:  # new (x', y') = (H - 1 - y, x)
            Kn = np.array([[fy, 0, H - 1 - cy], [0, fx, cx], [0, 0, 1.0]])
        # this frame's own gray image, turned: after `with_image` it is not its colour image's gray
        return RGBDFrame(np.ascontiguousarray(np.rot90(image, k)), np.ascontiguousarray(np.rot90(self.depth, k)),
                         Kn).with_image(np.rot90(self.image, k).copy())


def display_colour(image: np.ndarray) -> np.ndarray | None:
    """An (H, W, 3) uint8 BGR copy of an (H, W, 3) colour `image` as `to_gray` reads it (uint8 as it
    is, uint16 by its high byte, float in [0, 1] times 255, rounded), for display; None for any other
    shape (gray). A uint16 or float colour image was kept as no colour at all: its pictures were gray."""
    if image.ndim != 3 or image.shape[2] != 3:
        return None
    if not image.dtype.isnative:
        image = image.astype(image.dtype.newbyteorder("="))
    if image.dtype == np.uint8:
        return image.copy()
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    return np.clip(np.rint(image.astype(np.float32) * 255), 0, 255).astype(np.uint8)


def read_only(array: np.ndarray | None) -> np.ndarray | None:
    """`array` (a frame's own copy, never the caller's) made read-only, in place: no copy (None
    passes). Numpy then refuses an edit in place ("assignment destination is read-only")."""
    if array is not None:
        array.flags.writeable = False
    return array


def check_frame(frame, what: str = "frame") -> RGBDFrame:
    """`frame` when it is an RGBDFrame, else TypeError naming `what` (arguments swapped,
    compute(keypoints, frame), or a bare image were an AttributeError from deep inside)."""
    if not isinstance(frame, RGBDFrame):
        raise TypeError(f"{what}: expected an RGBDFrame, got {type(frame).__name__}")
    return frame


def too_thin_to_describe(frame: RGBDFrame, descriptor: str) -> bool:
    """Whether `frame` is under `MIN_FRAME_SIDE_PX` (2) pixels high or wide, warned of (naming the
    `descriptor`): one row or column of pixels has no neighbourhood across it, so every descriptor
    marks the frame's keypoints invalid, as for a frame without texture or depth (ORB failed with
    an OpenCV assertion on such a frame; SIFT, DAISY and the image-patch nets described the border
    pixels replicated across, GeoBit and GeoPatch a surface made up from one row of depth)."""
    H, W = check_frame(frame).shape
    if min(H, W) >= MIN_FRAME_SIDE_PX:
        return False
    warnings.warn(f"{descriptor}: the {W}x{H} frame is under {MIN_FRAME_SIDE_PX} pixels high or wide: a single row "
                  "or column of pixels has nothing around a keypoint to describe; every keypoint is invalid",
                  UserWarning, stacklevel=3)
    return True


def roll_camera(frame: RGBDFrame, angle_deg: float) -> tuple[RGBDFrame, np.ndarray]:
    """The frame seen by the same camera rolled about its optical axis by `angle_deg` (the image
    turns counter-clockwise as displayed for positive angles). Rotating the image about the principal
    point is exact for a roll when fx = fy and there is no skew; depth (Z) does not change, K stays.
    Pixels with no source get depth 0. The gray image is this frame's own, rolled (also when it is
    not its colour image's gray, as after `with_image`); the colour image is rolled with it.
    Returns the new frame and the (2, 3) affine map of pixels."""
    check_frame(frame)
    if isinstance(angle_deg, bool) or not isinstance(angle_deg, numbers.Real) or not math.isfinite(angle_deg):
        # NaN gave a NaN map, every pixel off the image, and "depth: every pixel is 0" naming no angle
        raise ValueError(f"angle_deg: expected a finite angle in degrees, got {angle_deg!r}")
    K = frame.K
    if abs(K[0, 0] - K[1, 1]) > 1e-6 * K[0, 0] or abs(K[0, 1]) > 1e-9:
        raise ValueError("K: roll_camera needs square pixels (fx = fy) and no skew")
    H, W = frame.shape
    A = cv2.getRotationMatrix2D((float(K[0, 2]), float(K[1, 2])), float(angle_deg), 1.0)
    image = frame.color if frame.color is not None else frame.image
    warped = cv2.warpAffine(image, A, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    depth = cv2.warpAffine(frame.depth, A, (W, H), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    rolled = RGBDFrame(warped, depth, K)
    if frame.color is not None and not np.array_equal(frame.image, to_gray(frame.color)):
        # a gray image of its own (`with_image`, e.g. filtered): roll that one, as `rotated90` turns it,
        # not the colour image's gray; the colour image is kept, rolled, for display
        gray = cv2.warpAffine(frame.image, A, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        rolled = rolled.with_image(np.clip(gray, 0.0, 1.0))
    return rolled, A


def quarter_turns(k: int) -> int:
    """`k` quarter turns (an integer of any sign, Python's or numpy's) as 0-3; TypeError naming `k` otherwise:
    `rotate_points90(points, shape, 1.5)` (or 0.5) turned the points by three quarter turns, without a word."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise TypeError(f"k: expected an integer number of quarter turns, got {k!r}")
    return int(k) % 4


def rotate_points90(points: np.ndarray, shape: tuple[int, int], k: int = 1) -> np.ndarray:
    """Map (N, 2) pixel coordinates of an (H, W) image into the image rotated by `np.rot90(., k)`
    (k: an integer number of quarter turns, any sign)."""
    k = quarter_turns(k)
    H, W = shape
    p = as_points(points, "points")
    x, y = p[:, 0], p[:, 1]
    if k == 0:
        return p.copy()
    if k == 1:
        return np.stack([y, W - 1 - x], axis=1)
    if k == 2:
        return np.stack([W - 1 - x, H - 1 - y], axis=1)
    return np.stack([H - 1 - y, x], axis=1)
