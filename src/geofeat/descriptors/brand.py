"""BRAND: Binary Robust Appearance and Normals Descriptor (Nascimento, Oliveira, Campos, Vieira &
Schwartz, "BRAND: A robust appearance and depth descriptor for RGB-D images", IROS 2012),
`make_descriptor("brand")`.

The method, as published and implemented here:

- **Scale from depth**: the patch covers a fixed metric extent, so its side in pixels shrinks with
  the keypoint's depth.
- **Orientation from the keypoint**: the sampling pattern is rotated by the keypoint's angle.
- **Pattern**: 256 point pairs (x_i, y_i) drawn once (seeded) from an isotropic Gaussian with
  sigma = S / 5 inside the S x S patch (BRIEF's G II layout).
- **Intensity test**: tau_I = I(x) < I(y) on a Gaussian-smoothed image.
- **Geometric test**: tau_G = (<n(x), n(y)> < cos(`NORMAL_ANGLE_DEG`)) and the pair is convex,
  kappa = <P(x) - P(y), n(x) - n(y)> > 0, with n the surface normals (pointing at the camera) and P
  the 3-D points from the depth map.
- **Bit** = tau_I OR tau_G (the paper's fusion of appearance and shape into one 256-bit string),
  packed to (N, 32) uint8 and compared with the Hamming distance.

Departures, and why: the paper maps depth to scale with an empirical piecewise-linear rule tuned to
Kinect ranges (constant below 2 m); we use the pinhole law it approximates, S = fx * extent / depth
across the image and fy * extent / depth down it, with `PATCH_EXTENT_M` = twice the geodesic
descriptors' support radius (0.15 m), so all RGB-D descriptors of the benchmark see the same surface
area. Normals come from central differences of the back-projected, lightly smoothed depth map (the
paper used PCL's integral-image normals).

Bad input: a frame without a depth map is a clear error; keypoints on missing depth (or whose
normal cannot be estimated) are `valid = False`; bare (N, 2) positions get angle 0 (documented
default; BRAND needs no keypoint size).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..constants import DEFAULT_RADIUS_M
from ..depth import backproject
from ..features import Features
from ..frame import RGBDFrame, too_thin_to_describe
from ..keypoints import as_keypoints
from .patches import keypoint_arrays
from .settings import merge_settings

#: Number of binary tests (bits).
N_BITS = 256
#: Metric side of the patch, metres.
PATCH_EXTENT_M = 2.0 * DEFAULT_RADIUS_M
#: Normals more than this angle apart (degrees) pass the geometric test's first half.
NORMAL_ANGLE_DEG = 45.0
#: Gaussian smoothing of the intensity image before the tests (sigma, pixels; BRIEF's value).
IMAGE_SIGMA_PX = 2.0
#: Gaussian smoothing of the depth map before the normals (sigma, pixels).
DEPTH_SIGMA_PX = 1.5
#: Half-step of the central differences used for the normals, pixels.
NORMAL_STEP_PX = 2


def brand_pattern(n_bits: int = N_BITS, seed: int = 0) -> np.ndarray:
    """(n_bits, 2, 2) pairs of (u, v) offsets in units of the patch side S, drawn from N(0, 1/25)
    and clipped to the patch [-1/2, 1/2]^2."""
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal(0.0, 0.2, size=(n_bits, 2, 2)), -0.5, 0.5)


def surface_normals(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) unit normals facing the camera and (H, W, 3) points (metres) of a depth map;
    NaN where the depth or a neighbour used by the differences is missing."""
    valid = depth > 0
    d = depth.astype(np.float32)
    blur = cv2.GaussianBlur(d, (0, 0), DEPTH_SIGMA_PX)
    weight = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), DEPTH_SIGMA_PX)
    smooth = np.where(valid, blur / np.maximum(weight, 1e-6), 0.0)
    P = backproject(smooth, K)
    s = NORMAL_STEP_PX
    dx = np.full_like(P, np.nan)
    dy = np.full_like(P, np.nan)
    dx[:, s:-s] = P[:, 2 * s:] - P[:, :-2 * s]
    dy[s:-s] = P[2 * s:] - P[:-2 * s]
    n = np.cross(dx, dy)
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    n *= -np.sign(np.sum(n * P, axis=2, keepdims=True))  # face the camera: <n, P> < 0
    return n, P


def _remap(channel: np.ndarray, mx: np.ndarray, my: np.ndarray, interpolation: int) -> np.ndarray:
    return cv2.remap(np.ascontiguousarray(channel, np.float32), mx, my, interpolation,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


@dataclass(frozen=True)
class BRANDSettings:
    """BRAND's options. n_bits: number of tests (multiple of 8; the paper: 256 or 512); seed: seed of
    the test pattern."""

    n_bits: int = N_BITS
    seed: int = 0


class BRAND:
    """BRAND descriptor: (N, 32) uint8 (256 bits), Hamming distance. See the module docstring.

    Options: `BRANDSettings`, given and merged as `geofeat.descriptors.settings` says.
    """

    name = "brand"
    binary, metric, geodesic = True, "hamming", False
    Settings = BRANDSettings

    def __init__(self, settings: BRANDSettings | Mapping[str, Any] | None = None, **kwargs: Any) -> None:
        self.settings = s = merge_settings(BRANDSettings, settings, kwargs)
        if s.n_bits <= 0 or s.n_bits % 8:
            raise ValueError(f"n_bits: expected a positive multiple of 8, got {s.n_bits}")
        self.pattern = brand_pattern(s.n_bits, s.seed)

    def compute(self, frame: RGBDFrame, keypoints) -> Features:
        """BRAND features of `keypoints` (Keypoints / cv2.KeyPoint list / (N, 2) pixels: angle 0)."""
        if not (hasattr(frame, "image") and hasattr(frame, "K")):  # keypoints and frame swapped, a bare image
            raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
        depth = getattr(frame, "depth", None)
        if depth is None or not hasattr(frame, "image") or not hasattr(frame, "K"):
            raise ValueError("frame: BRAND needs an RGB-D frame with a depth map (frame.depth), got none")
        depth = np.asarray(depth)
        if depth.shape != frame.image.shape or not (depth > 0).any():
            raise ValueError(f"frame: BRAND needs a depth map of the image's shape {frame.image.shape} with "
                             f"valid (> 0) values, got shape {depth.shape}")
        kps = as_keypoints(keypoints, depth.shape)
        xy, angles, _ = keypoint_arrays(kps, "brand", depth.shape)
        sizes = kps.sizes  # the detector's (NaN: none given), as every descriptor records them
        n, nb = len(xy), len(self.pattern)
        H, W = depth.shape
        normals, points = surface_normals(depth, frame.K)
        xi = np.clip(np.rint(xy[:, 0]).astype(int), 0, W - 1)
        yi = np.clip(np.rint(xy[:, 1]).astype(int), 0, H - 1)
        z = depth[yi, xi]
        # a frame 1 pixel high or wide: no keypoint is described, with a warning (`too_thin_to_describe`)
        valid = (z > 0) & np.isfinite(normals[yi, xi]).all(axis=1) & (not too_thin_to_describe(frame, self.name))
        # the patch's metric side in pixels along each image axis, fx E / z across and fy E / z down: with
        # fx alone for both, non-square pixels (an image resized from 16:9 to 4:3) covered fx / fy times
        # the extent down the image, and a quarter roll (fx and fy swap) changed a third of the bits
        extent = np.where(valid, PATCH_EXTENT_M / np.where(z > 0, z, 1.0), 0.0)  # metres per metre of depth
        side_x, side_y = frame.K[0, 0] * extent, frame.K[1, 1] * extent  # pixels
        a = np.radians(angles)
        c, s = np.cos(a)[:, None, None], np.sin(a)[:, None, None]
        u, v = self.pattern[None, ..., 0], self.pattern[None, ..., 1]  # (1, nb, 2)
        X = (xy[:, 0, None, None] + side_x[:, None, None] * (c * u - s * v)).reshape(n, 2 * nb).astype(np.float32)
        Y = (xy[:, 1, None, None] + side_y[:, None, None] * (s * u + c * v)).reshape(n, 2 * nb).astype(np.float32)
        out = np.zeros((n, nb // 8), np.uint8)
        if n == 0:
            return Features(xy, out, valid, angles=angles, sizes=sizes, scores=kps.scores, method=self.name)
        image = cv2.GaussianBlur(frame.image.astype(np.float32), (0, 0), IMAGE_SIGMA_PX)
        I = _remap(image, X, Y, cv2.INTER_LINEAR).reshape(n, nb, 2)
        N = np.stack([_remap(normals[..., k], X, Y, cv2.INTER_NEAREST) for k in range(3)], -1).reshape(n, nb, 2, 3)
        P = np.stack([_remap(points[..., k], X, Y, cv2.INTER_NEAREST) for k in range(3)], -1).reshape(n, nb, 2, 3)
        tau_i = I[..., 0] < I[..., 1]
        cos_n = np.sum(N[:, :, 0] * N[:, :, 1], axis=2)
        convex = np.sum((P[:, :, 0] - P[:, :, 1]) * (N[:, :, 0] - N[:, :, 1]), axis=2) > 0
        tau_g = (cos_n < np.cos(np.radians(NORMAL_ANGLE_DEG))) & convex  # NaN (no depth) -> False
        out = np.packbits(tau_i | tau_g, axis=1)
        out[~valid] = 0
        return Features(xy, out, valid, angles=angles, sizes=sizes, scores=kps.scores, method=self.name)
