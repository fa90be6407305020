"""Analytic surfaces with known geodesics, for checking the geodesic mapping f(.) sample by sample.

Each surface ray-casts its own depth map (`render`) and gives the exact point at geodesic distance s
from a start point along a start direction (`geodesic`): straight lines for a plane, helices for a
cylinder, straight lines of the unrolled sector for a cone (all three developable), great circles
for a sphere. `exact_samples` builds the exact polar patch of `geofeat.polar_patches`' convention
from its own reading of it: column 0 is the tangent direction whose image moves along image +x (the
tangent plane met by the ray of the pixel a little to the right), column k turns counter-clockwise as
displayed (towards the tangent direction whose image moves up), row i at geodesic distance
(i + 1) radius / n_rings.
"""

from __future__ import annotations

import numpy as np

import geofeat


def pixel_rays(K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) rays (x, y, 1) of every pixel (skew included)."""
    v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def project(K: np.ndarray, P: np.ndarray) -> np.ndarray:
    P = np.asarray(P, float)
    x, y = P[..., 0] / P[..., 2], P[..., 1] / P[..., 2]
    return np.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]], axis=-1)


def _nearest_root(a, b, c):
    """The smaller root of a t^2 + b t + c (NaN where there is none)."""
    disc = b * b - 4 * a * c
    return (-b - np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * a)


class Plane:
    def __init__(self, p0, n):
        n = np.asarray(n, float) / np.linalg.norm(n)
        self.p0, self.n = np.asarray(p0, float), n

    def depth(self, d):
        return (self.p0 @ self.n) / (d @ self.n)

    def normal(self, P):
        return np.broadcast_to(self.n, np.shape(P))

    def geodesic(self, P0, e, s):
        return P0 + s[:, None] * e


class Cylinder:
    """Radius R about the axis through c with direction a (the side facing the camera)."""

    def __init__(self, c, a, R):
        self.c, self.a, self.R = np.asarray(c, float), np.asarray(a, float) / np.linalg.norm(a), R

    def depth(self, d):
        dp = d - (d @ self.a)[..., None] * self.a
        cp = self.c - (self.c @ self.a) * self.a
        return _nearest_root((dp * dp).sum(-1), -2 * (dp @ cp), cp @ cp - self.R**2)

    def normal(self, P):
        q = P - self.c
        q = q - (q @ self.a)[..., None] * self.a
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    def geodesic(self, P0, e, s):
        """A helix: unrolled, a straight line (axial part s e.a, arc s e.t)."""
        q = P0 - self.c
        h0 = q @ self.a
        r = (q - h0 * self.a) / self.R
        t = np.cross(self.a, r)
        phi = s * (e @ t) / self.R
        return (self.c + (h0 + s * (e @ self.a))[:, None] * self.a
                + self.R * (np.cos(phi)[:, None] * r + np.sin(phi)[:, None] * t))


class Cone:
    """Apex V, unit axis a (away from the apex), half-angle alpha."""

    def __init__(self, V, a, alpha):
        self.V, self.a, self.alpha = np.asarray(V, float), np.asarray(a, float) / np.linalg.norm(a), alpha
        r = np.cross(self.a, [1.0, 0, 0] if abs(self.a[0]) < 0.9 else [0, 1.0, 0])
        self.r = r / np.linalg.norm(r)
        self.t = np.cross(self.a, self.r)

    def depth(self, d):
        c2 = np.cos(self.alpha) ** 2
        da, Va = d @ self.a, self.V @ self.a
        A, B, C = da * da - c2 * (d * d).sum(-1), -2 * (da * Va - c2 * (d @ self.V)), Va * Va - c2 * (self.V @ self.V)
        disc = B * B - 4 * A * C
        out = np.full(np.shape(A), np.nan)
        for sign in (1, -1):
            t = (-B + sign * np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * A)
            on = (t > 0) & (((t[..., None] * d - self.V) @ self.a) > 0)  # the nappe the axis points into
            out = np.where(on & ~(out < t), t, out)
        return out

    def normal(self, P):
        g = (P - self.V) / np.linalg.norm(P - self.V, axis=-1, keepdims=True)
        w = self.a - (g @ self.a)[..., None] * g
        return w / np.linalg.norm(w, axis=-1, keepdims=True)

    def geodesic(self, P0, e, s):
        """A straight line of the unrolled cone (a plane sector, polar angle phi sin(alpha))."""
        q = P0 - self.V
        rho0, phi0 = np.linalg.norm(q), np.arctan2(q @ self.t, q @ self.r)
        sa = np.sin(self.alpha)
        psi0 = phi0 * sa
        radial, around = e @ (q / rho0), e @ (np.cos(phi0) * self.t - np.sin(phi0) * self.r)
        u = np.array([np.cos(psi0), np.sin(psi0)])
        w = np.array([-np.sin(psi0), np.cos(psi0)])
        flat = rho0 * u + s[:, None] * (radial * u + around * w)
        rho = np.linalg.norm(flat, axis=1)
        psi = psi0 + (np.arctan2(flat[:, 1], flat[:, 0]) - psi0 + np.pi) % (2 * np.pi) - np.pi
        phi = psi / sa
        generator = np.cos(self.alpha) * self.a + sa * (np.cos(phi)[:, None] * self.r + np.sin(phi)[:, None] * self.t)
        return self.V + rho[:, None] * generator


class Sphere:
    def __init__(self, c, R):
        self.c, self.R = np.asarray(c, float), R

    def depth(self, d):
        return _nearest_root((d * d).sum(-1), -2 * (d @ self.c), self.c @ self.c - self.R**2)

    def normal(self, P):
        return (P - self.c) / self.R

    def geodesic(self, P0, e, s):
        """A great circle."""
        u = (P0 - self.c) / self.R
        return self.c + self.R * (np.cos(s / self.R)[:, None] * u + np.sin(s / self.R)[:, None] * e)


def render(surface, K: np.ndarray, shape: tuple[int, int], seed: int = 0) -> geofeat.RGBDFrame:
    """The surface's exact depth (0 where a pixel's ray misses it) under a random gray image."""
    z = surface.depth(pixel_rays(K, shape))
    depth = np.where(np.isfinite(z) & (z > 0), z, 0.0).astype(np.float32)
    image = np.random.default_rng(seed).random(shape).astype(np.float32)
    return geofeat.RGBDFrame(image, depth, K)


def exact_samples(surface, K: np.ndarray, keypoints: np.ndarray, radius: float, n_rings: int = 32,
                  n_angles: int = 32, eps_px: float = 1e-3) -> np.ndarray:
    """(N, n_rings, n_angles, 3) exact geodesic polar samples around the surface points under `keypoints`."""
    def ray(x, y):
        yy = (y - K[1, 2]) / K[1, 1]
        return np.array([(x - K[0, 2] - K[0, 1] * yy) / K[0, 0], yy, 1.0])

    s = np.arange(1, n_rings + 1) * radius / n_rings
    out = []
    for x, y in np.asarray(keypoints, float):
        d = ray(x, y)
        P0 = surface.depth(d[None])[0] * d
        n = surface.normal(P0[None])[0]

        def towards(x2, y2):  # the tangent direction whose image moves from (x, y) to (x2, y2)
            r = ray(x2, y2)
            v = (P0 @ n) / (r @ n) * r - P0
            return v / np.linalg.norm(v)

        e0 = towards(x + eps_px, y)
        e1 = np.cross(n, e0)
        e1 *= np.sign(e1 @ towards(x, y - eps_px))  # counter-clockwise as displayed: image up
        theta = 2 * np.pi * np.arange(n_angles) / n_angles
        out.append(np.stack([surface.geodesic(P0, np.cos(t) * e0 + np.sin(t) * e1, s) for t in theta], axis=1))
    return np.array(out)
