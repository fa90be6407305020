"""Analytic test scenes: a textured sheet, flat or bent into a cylinder, rendered by ray casting.

The sheet has material coordinates (u, v) in metres (u to the right, v down, as the image axes).
Flat: the plane Z = z0 facing the camera, point (u, v) at (X, Y, Z) = (u, v, z0).
Bent: the same sheet wrapped without stretching around a vertical cylinder of radius `bend_radius`
whose front line touches Z = z0 at X = 0: (u, v) -> (R sin(u / R), v, z0 + R (1 - cos(u / R))).
Both keep arc length, so geodesic distances on the sheet are identical in the two renderings and the
correspondence of a material point is known exactly (`project_flat` / `project_bent`).
"""

from __future__ import annotations

import cv2
import numpy as np

from geofeat import RGBDFrame

WIDTH, HEIGHT = 640, 480
K_SHEET = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
#: texture extent in metres (the texture repeats outside: it is periodic)
TEXTURE_SIZE_M = 0.8
TEXTURE_PX = 1024


def make_texture(seed: int = 0, size: int = TEXTURE_PX) -> np.ndarray:
    """(size, size) float32 periodic texture in [0, 1]: band-limited noise plus random blobs."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size), np.float32)
    for sigma, weight in ((1.5, 0.35), (4.0, 0.45), (12.0, 0.35)):
        noise = rng.standard_normal((size, size)).astype(np.float32)
        f = np.fft.fft2(noise)
        fy = np.fft.fftfreq(size)[:, None]
        fx = np.fft.fftfreq(size)[None, :]
        f *= np.exp(-2 * (np.pi * sigma) ** 2 * (fx**2 + fy**2))  # periodic Gaussian blur
        layer = np.real(np.fft.ifft2(f)).astype(np.float32)
        tex += weight * layer / layer.std()
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return tex


def _sample_texture(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear, periodic lookup of the texture at material coordinates (u, v) metres."""
    size = tex.shape[0]
    scale = size / TEXTURE_SIZE_M
    tx = np.mod(u * scale + size / 2, size).astype(np.float32)
    ty = np.mod(v * scale + size / 2, size).astype(np.float32)
    return cv2.remap(tex, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def _rays(K: np.ndarray = K_SHEET) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.arange(WIDTH, dtype=np.float64), np.arange(HEIGHT, dtype=np.float64))
    return (x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1]


def render_flat(tex: np.ndarray, z0: float = 0.6) -> RGBDFrame:
    """The flat sheet Z = z0 filling the image."""
    dx, dy = _rays()
    u, v = z0 * dx, z0 * dy
    image = _sample_texture(tex, u, v)
    depth = np.full((HEIGHT, WIDTH), z0, np.float32)
    return RGBDFrame(image, depth, K_SHEET)


def render_bent(tex: np.ndarray, z0: float = 0.6, bend_radius: float = 0.12) -> RGBDFrame:
    """The sheet wrapped on a vertical cylinder of radius `bend_radius` (front line at depth z0);
    pixels whose ray misses the cylinder, or meets it beyond the silhouette, have depth 0."""
    R = bend_radius
    dx, dy = _rays()
    zc = z0 + R
    # ray (t dx, t dy, t) meets (X)^2 + (Z - zc)^2 = R^2: (dx^2 + 1) t^2 - 2 zc t + zc^2 - R^2 = 0
    a = dx**2 + 1.0
    disc = zc**2 - a * (zc**2 - R**2)
    hit = disc > 0
    t = (zc - np.sqrt(np.maximum(disc, 0.0))) / a
    X, Y, Z = t * dx, t * dy, t
    u = R * np.arctan2(X, zc - Z)
    v = Y
    image = _sample_texture(tex, u, v)
    # keep surface facing the camera at under ~80 degrees from the view ray
    normal_x, normal_z = X / R, (Z - zc) / R
    cos_view = -(normal_x * dx + normal_z) / np.sqrt(a)
    ok = hit & (cos_view > 0.17)
    depth = np.where(ok, Z, 0.0).astype(np.float32)
    image = np.where(ok, image, 0.0).astype(np.float32)
    return RGBDFrame(image, depth, K_SHEET)


def project_flat(uv: np.ndarray, z0: float = 0.6) -> np.ndarray:
    """(N, 2) material points (u, v) metres -> (N, 2) pixels in the flat rendering."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([K_SHEET[0, 0] * uv[:, 0] / z0 + K_SHEET[0, 2], K_SHEET[1, 1] * uv[:, 1] / z0 + K_SHEET[1, 2]], 1)


def project_bent(uv: np.ndarray, z0: float = 0.6, bend_radius: float = 0.12) -> np.ndarray:
    """(N, 2) material points (u, v) metres -> (N, 2) pixels in the bent rendering."""
    uv = np.asarray(uv, dtype=np.float64)
    R = bend_radius
    X = R * np.sin(uv[:, 0] / R)
    Z = z0 + R * (1 - np.cos(uv[:, 0] / R))
    return np.stack([K_SHEET[0, 0] * X / Z + K_SHEET[0, 2], K_SHEET[1, 1] * uv[:, 1] / Z + K_SHEET[1, 2]], 1)


def sample_material_points(n: int, seed: int = 0, u_max: float = 0.06, v_max: float = 0.12) -> np.ndarray:
    """(n, 2) material points uniform in |u| <= u_max, |v| <= v_max metres, at least 8 mm apart."""
    rng = np.random.default_rng(seed)
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform([-u_max, -v_max], [u_max, v_max])
        if all(np.hypot(*(p - q)) >= 0.008 for q in pts):
            pts.append(p)
    return np.array(pts)
