"""Image patches around keypoints, oriented and scaled by the keypoint: the input of the image-only
baselines (TFeat-/Log-Polar-style nets in `image_patch_nets.py`, DaLI in `dali.py`).

A patch is an (S, S) grid of sample offsets in units of the support radius, rotated by the
keypoint's angle and scaled by its support radius (pixels), then sampled bilinearly with
`cv2.remap` in one call per chunk of keypoints. Large supports are sampled on a coarser level of
a Gaussian pyramid (level l where the sample step is about 2^l pixels), so a 32-sample patch over
a 200-pixel support is not aliased.

Angle convention: OpenCV's keypoint angle (degrees). A patch's +u axis points along
(cos a, sin a) in image pixels (x right, y down), so a patch follows the image when OpenCV's SIFT
orientation does. Pixels outside the image are replicated from the border (such keypoints stay
valid; OpenCV's SIFT handles its border keypoints the same way).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..keypoints import as_keypoints
from .baselines import check_angles, keypoint_sizes, warn_if_radians

#: Keypoints per cv2.remap call (remap maps must stay below 32767 rows).
_CHUNK = 512


def keypoint_arrays(keypoints, what: str,
                    shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xy (N, 2) pixels, angles (N,) degrees, sizes (N,) pixels) from `Keypoints`, a list of
    cv2.KeyPoint or an (N, 2) array. Bare positions get angle 0 and size `baselines.DEFAULT_SIZE_PX`
    (documented default of every image-patch descriptor); `what` names the descriptor in errors.
    With the image's (H, W) `shape`, keypoints off the image raise ValueError (as for every other
    descriptor), rather than being described from replicated border pixels; so do NaN or infinite
    angles, which would give NaN patches, and sizes that are not positive finite diameters
    (`keypoint_sizes`). Angles that look like radians warn (`warn_if_radians`)."""
    k = as_keypoints(keypoints, shape)
    check_angles(k.angles, what)
    warn_if_radians(k.angles, what)
    return k.xy.astype(np.float64), k.angles.astype(np.float64), keypoint_sizes(k.sizes, what)


def cartesian_grid(size: int) -> np.ndarray:
    """(size, size, 2) offsets (u, v) in [-1, 1] (units of the support radius), row = v, column = u."""
    t = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    u, v = np.meshgrid(t, t)
    return np.stack([u, v], axis=-1)


def logpolar_grid(n_radii: int, n_angles: int, min_radius: float) -> np.ndarray:
    """(n_radii, n_angles, 2) offsets on log-spaced circles from `min_radius` to 1 (units of the
    support radius); row i = radius, column k = angle 2 pi k / n_angles from the patch's +u axis."""
    r = np.exp(np.linspace(np.log(min_radius), 0.0, n_radii))
    a = 2.0 * np.pi * np.arange(n_angles) / n_angles
    return np.stack([r[:, None] * np.cos(a)[None, :], r[:, None] * np.sin(a)[None, :]], axis=-1)


def sample_patches(image: np.ndarray, xy: np.ndarray, angles_deg: np.ndarray, radius_px: np.ndarray,
                   grid: np.ndarray) -> np.ndarray:
    """Sample `grid` around every keypoint.

    Args:
        image: (H, W) float32 gray image in [0, 1].
        xy: (N, 2) keypoint pixels; angles_deg: (N,) OpenCV angles, degrees; radius_px: (N,)
            support radius, pixels (the grid's unit).
        grid: (P, Q, 2) offsets (u, v) in units of the support radius.

    Returns:
        (N, P, Q) float32 samples.
    """
    image = np.ascontiguousarray(image, dtype=np.float32)
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    n = len(xy)
    P, Q = grid.shape[:2]
    out = np.zeros((n, P, Q), np.float32)
    if n == 0:
        return out
    radius_px = np.broadcast_to(np.asarray(radius_px, np.float64), (n,))
    if not np.all(np.isfinite(radius_px) & (radius_px > 0)):
        raise ValueError("radius_px: expected positive finite support radii (pixels)")
    a = np.radians(np.asarray(angles_deg, np.float64).reshape(n))
    c, s = np.cos(a)[:, None, None], np.sin(a)[:, None, None]
    u, v = grid[None, ..., 0], grid[None, ..., 1]
    r = radius_px[:, None, None]
    X = xy[:, 0, None, None] + r * (c * u - s * v)
    Y = xy[:, 1, None, None] + r * (s * u + c * v)
    step = 2.0 * radius_px / max(P, Q)  # pixels between neighbouring samples
    levels = np.clip(np.floor(np.log2(np.maximum(step, 1.0))).astype(int), 0, 5)
    pyramid = [image]
    for _ in range(int(levels.max())):
        pyramid.append(cv2.pyrDown(pyramid[-1]))
    for level in np.unique(levels):
        f = 2.0 ** level
        idx = np.flatnonzero(levels == level)
        for start in range(0, len(idx), _CHUNK):
            sel = idx[start:start + _CHUNK]
            # cv2.pyrDown centres pixel i of a level on pixel 2 i of the level below: pixel i of
            # level l on full-resolution pixel f * i
            mx = (X[sel] / f).reshape(-1, Q).astype(np.float32)
            my = (Y[sel] / f).reshape(-1, Q).astype(np.float32)
            out[sel] = cv2.remap(pyramid[level], mx, my, cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_REPLICATE).reshape(len(sel), P, Q)
    return out
