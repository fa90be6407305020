"""OpenCV baselines behind the same interface as GeoBit / GeoPatch: `compute(frame, keypoints)`.

Every baseline describes the given keypoints (usually SIFT's) with SIFT's orientation, and with a
support size derived from SIFT's size where the descriptor uses one (`SIZE_FACTORS`, chosen as each
entry says; `benchmarks/bench_baseline_scaling.py` measures their rotation and scale invariance on a
rotated and a scaled copy of the demo frame):

- ORB: uses the given angle, and describes each keypoint on the level of its own pyramid
  (8 levels, factor 1.2) where its 31-pixel patch is closest to 12x SIFT's size (`orb_level`), as
  ORB describes the keypoints it detects: OpenCV reads the level from `cv2.KeyPoint.octave`, and at
  level 0 (what it got before) every keypoint had the same 31 px patch whatever its size, so ORB
  could not follow a scale change. 12x was chosen by matching score on the six validation sequences
  named below (mean 0.151 at level 0; 0.168 / 0.178 / 0.193 / 0.189 at 6 / 8 / 12 / 16x).
- BRISK, FREAK: scale their sampling pattern with the keypoint size, and estimate their own
  orientation from the pattern (the given angle changes nothing). They get 4x SIFT's size: the
  factor with the best matching score under the benchmark's protocol on six held-out `paper`
  validation sequences (`benchmarks/make_sim_datasets.py --train 0 --val 6 --test 0
  --val-presets paper`, seeds 2000-2005, 2048 protocol keypoints; BRISK 0.161 / 0.190 / 0.223 /
  0.228 / 0.225 / 0.223 / 0.213 and FREAK 0.163 / 0.191 / 0.214 / 0.211 / 0.202 / 0.190 / 0.163
  at 1 / 2 / 3 / 4 / 5 / 6 / 8x). Small factors lose scale invariance (BRISK and FREAK clamp small
  sizes to their smallest pattern); large ones lose keypoints near the image border, which OpenCV
  drops (valid = False, a miss in the matching score: FREAK keeps 0.89 of them at 4x on val000,
  0.75 at 6x) and deformation-robustness. The earlier 6x was chosen on the correct-match rate of
  the keypoints both sides kept, 40 px inside a rigidly scaled image, which hid both costs.
- DAISY: fixed radius (15 px), no size; uses the given angle when `use_orientation=True`. Each of
  its 25 histograms is normalised to unit length (`norm=DAISY_NRM_PARTIAL`, the normalisation of
  Tola et al.'s DAISY and of their reference code; OpenCV's default, NRM_NONE, leaves raw gradient
  magnitudes, which change with the image's contrast and shading).
- SIFT: uses size and angle as detected, and the pyramid octave and layer its size was detected at
  (`sift_octave`): OpenCV's SIFT `compute` reads them from `cv2.KeyPoint.octave`, which
  `Keypoints` does not keep; at octave 0 every keypoint would be described on the first, least
  blurred pyramid image, not SIFT's own descriptor.

OpenCV drops keypoints it cannot describe (too close to the border); those come back with
`valid = False` and zero descriptors, in the input order. So do DAISY's keypoints at x < 0 or y < 0
(on the image's first pixel, which spans [-0.5, 0.5)), which OpenCV's DAISY refuses with an error.
Angles are passed modulo 360 (DAISY asserts 0 <= angle < 360; cv2.KeyPoint's default angle is -1);
NaN or infinite angles raise ValueError (ORB crashed the process on them).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..features import Features
from ..frame import RGBDFrame, check_frame, too_thin_to_describe
from ..inputs import check_positive
from ..keypoints import as_keypoints, to_uint8

#: SIFT diameter -> descriptor size factors (see module docstring).
SIZE_FACTORS = {"orb": 12.0, "brisk": 4.0, "freak": 4.0, "daisy": 1.0, "sift": 1.0}
#: Keypoint size used when the caller gives none (pixels).
DEFAULT_SIZE_PX = 8.0
#: OpenCV SIFT's defaults (`cv2.SIFT_create()`): layers per octave and base blur (sigma, pixels).
SIFT_LAYERS, SIFT_SIGMA = 3, 1.6


def sift_octave(sizes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """OpenCV SIFT's packed `cv2.KeyPoint.octave` (octave & 255 | layer << 8) of keypoints of
    diameter `sizes` (pixels) on an image of `shape` (H, W): SIFT detects a keypoint of octave o
    (-1 = the upsampled image) and layer l (1..3) with diameter 2 sigma 2^(o + (l + xi) / 3),
    |xi| <= 1/2, so 3 log2(size / (2 sigma)) rounds to 3 o + l. Octaves are clipped to those the
    image has (o <= log2(min(H, W)) - 3)."""
    q = np.rint(SIFT_LAYERS * np.log2(np.maximum(np.asarray(sizes, np.float64), 1e-3) / (2.0 * SIFT_SIGMA)))
    q = np.clip(q, 1 - SIFT_LAYERS, None).astype(np.int64)  # octave -1, layer 1 at the least
    octave = np.floor_divide(q - 1, SIFT_LAYERS)
    top = max(int(np.round(np.log2(max(min(shape), 1)))) - 3, 0)
    layer = np.where(octave > top, SIFT_LAYERS, q - SIFT_LAYERS * octave)
    octave = np.minimum(octave, top)
    return (octave & 255) | (layer << 8)


def orb_level(sizes: np.ndarray, patch_size: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """ORB's pyramid level (`cv2.KeyPoint.octave`) for supports of `sizes` pixels: the level whose
    patch, `patch_size` x `scale_factor` ** level pixels of the image, is nearest in log scale."""
    level = np.rint(np.log(np.maximum(np.asarray(sizes, np.float64), 1e-3) / patch_size) / np.log(scale_factor))
    return np.clip(level, 0, n_levels - 1).astype(np.int64)


def _make_extractor(name: str):
    if name == "orb":
        return cv2.ORB_create(edgeThreshold=31, patchSize=31)
    if name == "brisk":  # in cv2 up to OpenCV 4, in xfeatures2d (contrib) from OpenCV 5
        return (getattr(cv2, "BRISK_create", None) or cv2.xfeatures2d.BRISK_create)()
    if name == "freak":
        return cv2.xfeatures2d.FREAK_create()
    if name == "daisy":
        return cv2.xfeatures2d.DAISY_create(norm=cv2.xfeatures2d.DAISY_NRM_PARTIAL, use_orientation=True)
    if name == "sift":
        return cv2.SIFT_create()
    raise ValueError(f"descriptor: unknown OpenCV baseline {name!r}; expected one of {sorted(SIZE_FACTORS)}")


#: The baselines that describe at the given keypoint angle (BRISK and FREAK estimate their own).
USES_GIVEN_ANGLE = ("orb", "daisy", "sift")
#: The baselines whose support follows the keypoint size (DAISY's radius is fixed).
USES_SIZE = ("orb", "brisk", "freak", "sift")


def check_angles(angles: np.ndarray, name: str) -> None:
    """Keypoint angles (degrees) must be finite: OpenCV's ORB crashes the process on a NaN or infinite
    angle, DAISY asserts, SIFT returns all-zero descriptors; the patch descriptors would be NaN."""
    bad = ~np.isfinite(np.asarray(angles, np.float64))
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"keypoints: {int(bad.sum())} keypoint angle(s) are NaN or infinite (e.g. #{i}); {name} "
                         "describes at the given angle: give angles in degrees (0 for upright keypoints)")


def keypoint_sizes(sizes: np.ndarray, name: str) -> np.ndarray:
    """(N,) float64 keypoint diameters, pixels, for descriptor `name`, which describes at the keypoint's
    size: NaN (unknown, as for keypoints given as bare (N, 2) pixels) becomes `DEFAULT_SIZE_PX`. A size
    that is not a positive finite diameter (0, negative, inf) is a ValueError naming `name`: SIFT, ORB,
    BRISK and FREAK described it at 1 px (the smallest support they take) and inf at the default size,
    without a word; a negative diameter is no keypoint size, and 0 is what cv2.KeyPoint() leaves unset."""
    sizes = np.asarray(sizes, np.float64)
    bad = ~np.isnan(sizes) & ~(np.isfinite(sizes) & (sizes > 0))
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"keypoints: {int(bad.sum())} keypoint size(s) are not positive finite diameters (e.g. #{i}: "
                         f"{sizes[i]:g}); {name} describes at the keypoint's size: give diameters in pixels, or NaN "
                         f"where unknown ({DEFAULT_SIZE_PX:g} px is used)")
    return np.where(np.isnan(sizes), DEFAULT_SIZE_PX, sizes)


#: Keypoints with a non-zero angle, all within one turn in radians, that make `warn_if_radians` warn: OpenCV's
#: degrees in [0, 360) fall there for 8 keypoints with probability (2 pi / 360) ** 8, about 1e-14.
RADIAN_EVIDENCE = 8


def warn_if_radians(angles: np.ndarray, name: str) -> None:
    """Warn when keypoint angles (N,) look like radians: at least `RADIAN_EVIDENCE` of them non-zero and
    every one within [-2 pi, 2 pi]. Angles are degrees (OpenCV's convention, `Keypoints.angles`); radians
    (scikit-image's ORB orientations, `np.arctan2`) turned each patch by a 57th of its angle, a
    descriptor no longer rotation-invariant, without a word."""
    a = np.asarray(angles, np.float64)
    a = a[np.isfinite(a)]
    if np.count_nonzero(a) >= RADIAN_EVIDENCE and np.abs(a).max() <= 2 * np.pi + 1e-6:
        warnings.warn(f"{name}: every keypoint angle lies within [-2 pi, 2 pi] ({len(a)} keypoints, largest "
                      f"{np.abs(a).max():.3g}): radians? Keypoint angles are degrees (OpenCV's convention); pass "
                      "np.degrees(angles)", UserWarning, stacklevel=3)


@dataclass
class OpenCVDescriptor:
    """An OpenCV descriptor on given keypoints.

    Attributes:
        name: "orb", "brisk", "freak", "daisy" or "sift".
        use_angle: pass the keypoints' orientation (False: angle 0 for every keypoint).
        size_factor: multiplies the keypoints' size (default: `SIZE_FACTORS[name]`).
    """

    name: str
    use_angle: bool = True
    size_factor: float | None = None
    geodesic: bool = field(default=False, init=False)
    _extractor: object = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.name = self.name.lower()
        self._extractor = _make_extractor(self.name)
        self.binary = self._extractor.descriptorType() == cv2.CV_8U
        self.metric = "hamming" if self.binary else "l2"
        if self.size_factor is None:
            self.size_factor = SIZE_FACTORS[self.name]
        # a negative or NaN factor was described at 1 px (the smallest support), inf at DEFAULT_SIZE_PX
        self.size_factor = check_positive(self.size_factor, f"{self.name}: size_factor")

    def compute(self, frame: RGBDFrame, keypoints) -> Features:
        """Describe `keypoints` (see `geofeat.keypoints.as_keypoints`) on `frame.image`; a keypoint
        without a size (an (N, 2) array) gets `DEFAULT_SIZE_PX`, without an angle 0. Returns Features
        with (N, D) descriptors (uint8 for the binary ones, float32 for SIFT and DAISY); on a frame
        1 pixel high or wide every keypoint is invalid, with a warning (`too_thin_to_describe`)."""
        kps = as_keypoints(keypoints, check_frame(frame).shape)
        n = len(kps)
        thin = too_thin_to_describe(frame, self.name)
        if self.use_angle and self.name in USES_GIVEN_ANGLE and n > 1 and not np.any(kps.angles):
            warnings.warn(f"{self.name}: every keypoint has angle 0 (GeoKey's keypoints and (N, 2) arrays carry "
                          f"no orientation), so the descriptor is not rotation-invariant; detect with "
                          f"detector='sift' to use SIFT's orientation", stacklevel=2)
        # DAISY's radius is fixed: its keypoints' sizes are not read
        sizes = (keypoint_sizes(kps.sizes, self.name) if self.name in USES_SIZE
                 else np.where(np.isfinite(kps.sizes), kps.sizes, DEFAULT_SIZE_PX))
        angles = np.zeros(n)
        if self.use_angle:
            check_angles(kps.angles, self.name)
            if self.name in USES_GIVEN_ANGLE:  # BRISK and FREAK estimate their own
                warn_if_radians(kps.angles, self.name)
            # the same angle in [0, 360): DAISY asserts that range (cv2.KeyPoint's default angle is -1)
            angles = np.mod(kps.angles, 360.0).astype(np.float32)
            angles[angles >= 360.0] = 0.0  # -1e-9 % 360 rounds to 360 in float32
        sizes = np.maximum(sizes * self.size_factor, 1.0)
        octaves = np.zeros(n, np.int64)
        if self.name == "sift":
            octaves = sift_octave(sizes, frame.shape)
        elif self.name == "orb":
            orb = self._extractor
            octaves = orb_level(sizes, orb.getPatchSize(), orb.getScaleFactor(), orb.getNLevels())
            sizes = orb.getPatchSize() * orb.getScaleFactor() ** octaves.astype(np.float64)  # what ORB describes
        cv_kps = [
            cv2.KeyPoint(float(x), float(y), float(s), float(a), 0.0, int(o), i)
            for i, ((x, y), s, a, o) in enumerate(zip(kps.xy, sizes, angles, octaves))
            # DAISY asserts x, y >= 0 (an OpenCV error); the first pixel row and column reach -0.5
            if not thin and (self.name != "daisy" or (x >= 0 and y >= 0))
        ]
        if self.name == "sift" and cv_kps:
            # OpenCV's SIFT builds its pyramid from octave min(0, lowest octave given): one keypoint of
            # octave -1 (dropped below) makes it always the upsampled image, as detectAndCompute does,
            # so a keypoint's descriptor does not depend on the other keypoints of the call
            H, W = frame.shape
            cv_kps.append(cv2.KeyPoint(W / 2.0, H / 2.0, 2.0, 0.0, 0.0, 255 | 1 << 8, -1))
        # none to describe: no call (ORB's pyramid asserts on a frame 1 pixel high or wide, whatever the keypoints)
        kept, desc = self._extractor.compute(to_uint8(frame.image), cv_kps) if cv_kps else ((), None)
        dim = self._extractor.descriptorSize()
        dtype = np.uint8 if self._extractor.descriptorType() == cv2.CV_8U else np.float32
        out = np.zeros((n, dim), dtype)
        valid = np.zeros(n, bool)
        if desc is not None and len(kept):
            index = np.array([k.class_id for k in kept], dtype=np.int64)
            mine = index >= 0  # not the octave -1 keypoint added for SIFT
            out[index[mine]] = desc[mine].astype(dtype)
            valid[index[mine]] = True
        return Features(kps.xy, out, valid, angles=kps.angles, sizes=kps.sizes, scores=kps.scores, method=self.name)


BASELINES = tuple(SIZE_FACTORS)
