"""Analytic test scenes: a textured sheet seen flat and bent around a cylinder (exact ray casting),
with the exact correspondence between the two views. Shared by the geodesic and descriptor tests."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

import geofeat

K_VGA = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
SHEET_HALF_WIDTH = 0.30  # metres, along the bending direction s
SHEET_HALF_HEIGHT = 0.22  # metres, along t


def sheet_texture(seed: int = 0, size_px: int = 1200, mm_per_px: float = 0.5) -> tuple[np.ndarray, float]:
    """A random blob texture covering the sheet: (size_px, size_px) float32 in [0, 1] and its
    resolution in metres per texel. Blobs of a few millimetres to centimetres."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size_px, size_px), np.float32)
    for sigma in (3, 8, 20):
        noise = rng.standard_normal((size_px, size_px)).astype(np.float32)
        tex += cv2.GaussianBlur(noise, (0, 0), sigma) * sigma
    tex -= tex.min()
    tex /= tex.max()
    return tex, mm_per_px / 1000.0


def _texture_at(tex: np.ndarray, m_per_texel: float, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    n = tex.shape[0]
    map_x = (s / m_per_texel + n / 2).astype(np.float32)
    map_y = (t / m_per_texel + n / 2).astype(np.float32)
    return cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


@dataclass
class Sheet:
    """A sheet at distance z0 (metres), flat (bend_radius=None) or wrapped around a vertical
    cylinder of radius bend_radius that touches the flat sheet's plane at s = 0."""

    z0: float = 1.0
    bend_radius: float | None = None
    K: np.ndarray = field(default_factory=lambda: K_VGA.copy())
    shape: tuple[int, int] = (480, 640)

    def surface_point(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Sheet coordinates (s, t) in metres -> (N, 3) camera-frame points."""
        s, t = np.asarray(s, float), np.asarray(t, float)
        if self.bend_radius is None:
            return np.stack([s, t, np.full_like(s, self.z0)], axis=-1)
        R = self.bend_radius
        return np.stack([R * np.sin(s / R), t, self.z0 + R - R * np.cos(s / R)], axis=-1)

    def project(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        P = self.surface_point(s, t)
        x = self.K[0, 0] * P[..., 0] / P[..., 2] + self.K[0, 2]
        y = self.K[1, 1] * P[..., 1] / P[..., 2] + self.K[1, 2]
        return np.stack([x, y], axis=-1)

    def render(self, tex: np.ndarray, m_per_texel: float) -> geofeat.RGBDFrame:
        """Ray-cast the sheet: gray image in [0, 1] (background 0.5) and depth in metres (0 off the sheet)."""
        H, W = self.shape
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        dx = (u - self.K[0, 2]) / self.K[0, 0]
        dy = (v - self.K[1, 2]) / self.K[1, 1]
        if self.bend_radius is None:
            z = np.full_like(dx, self.z0)
            X, Y = dx * z, dy * z
            s, t = X, Y
        else:
            R, zc = self.bend_radius, self.z0 + self.bend_radius
            # ray (dx, dy, 1) * z meets X^2 + (Z - zc)^2 = R^2: (dx^2 + 1) z^2 - 2 zc z + zc^2 - R^2 = 0
            a = dx**2 + 1.0
            disc = zc**2 - a * (zc**2 - R**2)
            hit = disc >= 0
            z = np.where(hit, (zc - np.sqrt(np.maximum(disc, 0))) / a, np.nan)
            X, Y = dx * z, dy * z
            s = R * np.arctan2(X, zc - z)
            t = Y
        on = np.isfinite(z) & (np.abs(s) <= SHEET_HALF_WIDTH) & (np.abs(t) <= SHEET_HALF_HEIGHT)
        gray = np.where(on, _texture_at(tex, m_per_texel, np.nan_to_num(s), np.nan_to_num(t)), 0.5)
        depth = np.where(on, z, 0.0).astype(np.float32)
        return geofeat.RGBDFrame(gray.astype(np.float32), depth, self.K)


def sheet_pair(bend_radius: float = 0.12, seed: int = 0):
    """(flat frame, bent frame, flat sheet, bent sheet) of the same texture."""
    tex, m = sheet_texture(seed)
    flat, bent = Sheet(), Sheet(bend_radius=bend_radius)
    return flat.render(tex, m), bent.render(tex, m), flat, bent


def corresponding_points(flat: Sheet, bent: Sheet, n: int = 100, seed: int = 1, margin: float = 0.09):
    """n random sheet points at least `margin` metres inside the sheet and visible in both views
    with a 75 mm geodesic disc around them that stays in front of the bent sheet's silhouette;
    returns (xy_flat (n, 2), xy_bent (n, 2))."""
    rng = np.random.default_rng(seed)
    s_max = min(SHEET_HALF_WIDTH - margin, 0.9 * np.pi / 2 * (bent.bend_radius or 1e9) - 0.075)
    s = rng.uniform(-s_max, s_max, n)
    t = rng.uniform(-(SHEET_HALF_HEIGHT - margin), SHEET_HALF_HEIGHT - margin, n)
    return flat.project(s, t), bent.project(s, t)


def plane_frame(shape=(480, 640), z0: float = 1.0, seed: int = 0) -> geofeat.RGBDFrame:
    """A fronto-parallel plane at z0 metres with a random texture."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min())
    K = K_VGA.copy()
    K[0, 2], K[1, 2] = (shape[1] - 1) / 2, (shape[0] - 1) / 2  # the principal point of this image size
    return geofeat.RGBDFrame(img, np.full(shape, z0, np.float32), K)


def write_rolled_kinect_sequence(folder, angle_deg: float):
    """Write the shipped Kinect frame (reference `cloud_ref`) and its copy with the camera rolled by
    `angle_deg` (`cloud_roll<angle>`), with the shipped landmarks moved along, into `folder` in the
    public layout (PNG colour and millimetre depth, intrinsics.xml, one landmark csv per frame)."""
    from geofeat.frame import roll_camera
    from geofeat.io import demo_data_dir, read_landmarks, write_frame, write_intrinsics, write_landmarks

    frame = geofeat.read_demo_frame()
    ids, xy, visible = read_landmarks(demo_data_dir() / "cloud_1.csv")
    write_intrinsics(folder / "intrinsics.xml", frame.K)
    write_frame(folder, "cloud_ref", frame.color, frame.depth)
    write_landmarks(folder / "cloud_ref.csv", ids, xy, visible)
    rolled, A = roll_camera(frame, angle_deg)
    name = f"cloud_roll{angle_deg:g}"
    write_frame(folder, name, rolled.color, rolled.depth)
    write_landmarks(folder / f"{name}.csv", ids, xy @ A[:, :2].T + A[:, 2], visible)
    return folder
