"""Image similarity used to judge a warp: SSIM, from OpenCV's maintained `quality` module.

One SSIM for the whole package (tracking's per-frame confidence, the ground-truth reports and
their SSIM pictures): Gaussian 11 x 11 window, sigma 1.5, the constants of Wang et al. (2004).
"""

from __future__ import annotations

import cv2
import numpy as np

from .frame import to_gray


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) float32 SSIM of two (H, W) gray images with values in [0, 1] (uint8 and uint16 images
    are read as fractions of their full scale, as `frame.to_gray` reads them)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"ssim: expected two gray images of one shape, got {a.shape} and {b.shape}")
    # SSIM's constants are for [0, 1] (scaled to 255 below): a 0-255 image was scaled twice over
    a, b = to_gray(a), to_gray(b)
    _, qmap = cv2.quality.QualitySSIM_compute(a * 255.0, b * 255.0)
    qmap = np.asarray(qmap[0] if isinstance(qmap, (tuple, list)) else qmap)
    if qmap.ndim == 3:
        qmap = qmap[..., 0]
    return qmap.astype(np.float32)


def mean_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM of two gray images in [0, 1] over the (H, W) bool `mask` (all pixels when None);
    NaN when the mask is empty."""
    qmap = ssim_map(a, b)
    m = np.ones(qmap.shape, bool) if mask is None else np.asarray(mask, bool)
    if m.shape != qmap.shape:
        raise ValueError(f"mask: expected shape {qmap.shape}, the images', got {m.shape}")
    return float(qmap[m].mean()) if m.any() else float("nan")
