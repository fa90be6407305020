"""Sensor noise: Gaussian pixel noise on colour, and a Kinect-like depth-noise model.

The depth model (optional) follows the usual structured-light description: axial noise whose
standard deviation grows with the square of the distance (Nguyen et al. 2012:
sigma_z = 1.2 mm + 1.9 mm * (z - 0.4 m)^2), plus holes where the sensor loses the pattern:
near depth discontinuities and the silhouette, on surfaces seen at grazing angles, and in a few
random blobs. Ground truth ((u, v) maps) is never affected.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
from numba import njit, prange
from scipy.special import ndtri


@njit(cache=True, inline="always")
def _mix64(x):
    """splitmix64 finaliser: a well-mixed 64-bit hash of x (uint64)."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@functools.cache
def normal_table() -> np.ndarray:
    """(2^16,) float32 quantiles of the standard normal, N^-1((i + 0.5) / 2^16): a pixel's hash picks
    three of them. The table reproduces the normal's mean and variance to 1e-4, tails to 4.3 sigma."""
    return ndtri((np.arange(1 << 16) + 0.5) / (1 << 16)).astype(np.float32)


@njit(cache=True, parallel=True)
def _finish(color, mask, background, sigma, key, table):
    """uint8 image = clip(round(255 * (mask ? color : background) + sigma * g)), g a standard normal
    from `table` indexed by three 16-bit fields of a counter-based hash of (key, pixel): deterministic
    and independent of the number of threads."""
    H, W = mask.shape
    out = np.empty((H, W, 3), dtype=np.uint8)
    k0 = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    for y in prange(H):
        for x in range(W):
            h = _mix64(k0 + np.uint64(y * W + x))
            for k in range(3):
                g = table[(h >> np.uint64(16 * k)) & np.uint64(0xFFFF)]
                c = color[y, x, k] if mask[y, x] else background[k]
                v = np.floor(c * 255.0 + sigma * g + 0.5)
                out[y, x, k] = np.uint8(min(max(v, 0.0), 255.0))
    return out


def finish_image(color: np.ndarray, mask: np.ndarray, background: np.ndarray, sigma: float,
                 rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float [0, 1] colour, background (3,) BGR [0, 1] where mask (H, W) is False, plus
    Gaussian pixel noise of `sigma` grey levels -> (H, W, 3) uint8 (seeded by rng)."""
    key = int(rng.integers(0, 2**62))
    return _finish(np.ascontiguousarray(color, dtype=np.float32), np.ascontiguousarray(mask),
                   np.asarray(background, dtype=np.float64), float(sigma), key, normal_table())


def motion_blur(color: np.ndarray, length_px: float, angle: float) -> np.ndarray:
    """(H, W, 3) image blurred by a centred line kernel of `length_px` pixels at `angle` radians (a
    straight camera / object motion during the exposure); unchanged below 1 px.

    The kernel is the segment of length `length_px - 1` through the kernel centre, sampled densely and
    splatted bilinearly (1 px wide): symmetric about the centre, so the blur moves no image content
    and the ground truth (the cloth at mid-exposure) stays exact. Returns float32.
    """
    if length_px < 1.0:
        return color
    size = (int(np.ceil(length_px)) | 1) + 2  # odd, with a margin for the splat
    c, h = (size - 1) // 2, (length_px - 1) / 2.0
    samples = max(64, 4 * size)  # well under a pixel apart along the segment
    t = (np.arange(samples) + 0.5) / samples * 2 - 1  # symmetric about 0 in (-1, 1)
    x, y = c + t * h * np.cos(angle), c + t * h * np.sin(angle)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    kernel = np.zeros((size, size), np.float64)
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(kernel, (y0 + dy, x0 + dx), w)
    kernel = (kernel / kernel.sum()).astype(np.float32)
    return cv2.filter2D(np.ascontiguousarray(color, dtype=np.float32), -1, kernel, borderType=cv2.BORDER_REPLICATE)


def depth_noise_sigma(z: np.ndarray | float) -> np.ndarray | float:
    """Standard deviation (metres) of the axial depth noise at depth `z` metres (Nguyen et al. 2012)."""
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def kinect_depth_noise(
    depth: np.ndarray,
    cos_view: np.ndarray,
    rng: np.random.Generator,
    edge_px: int = 2,
    grazing_cos: float = 0.25,
    n_blobs: int = 4,
) -> np.ndarray:
    """Kinect-like noisy copy of an (H, W) float32 depth map in metres (0 = missing).

    Args:
        depth: clean depth, metres.
        cos_view: (H, W) |cos| between the surface normal and the viewing ray.
        rng: random generator.
        edge_px: holes within about this many pixels of a depth discontinuity (> 2 cm) or of the
            silhouette, each pixel dropped with probability 0.6.
        grazing_cos: pixels with cos_view below this are dropped.
        n_blobs: number of random elliptic dropouts (radius 2..8 px).
    """
    valid = depth > 0
    z = depth.astype(np.float32)
    sigma = depth_noise_sigma(z)
    noisy = z + rng.standard_normal(z.shape, dtype=np.float32) * sigma
    # discontinuities: background next to foreground, or a jump > 2 cm between neighbours
    big = np.where(valid, z, 1e3).astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    jump = (cv2.dilate(big, k) - cv2.erode(big, k)) > 0.02
    near_edge = cv2.dilate(jump.astype(np.uint8), np.ones((2 * edge_px - 1, 2 * edge_px - 1), np.uint8)) > 0
    drop = (near_edge & (rng.random(z.shape) < 0.6)) | (cos_view < grazing_cos)
    holes = np.zeros(z.shape, np.uint8)
    ys, xs = np.nonzero(valid)
    if len(ys):
        for i in rng.integers(0, len(ys), n_blobs):
            axes = (int(rng.integers(2, 9)), int(rng.integers(2, 9)))
            cv2.ellipse(holes, (int(xs[i]), int(ys[i])), axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    drop |= holes > 0
    return np.where(valid & ~drop, np.maximum(noisy, 0), 0).astype(np.float32)
