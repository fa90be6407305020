"""Headless z-buffer rasteriser for the cloth mesh (numba, CPU only).

Conventions: camera coordinates x right, y down, z forward (metres); pixel coordinates in the
OpenCV convention (the centre of the top-left pixel is (0, 0)), x = fx X / Z + cx. A pixel is
covered by a triangle when its centre lies inside the projected triangle; depth, (u, v) and the
normal are interpolated perspective-correctly, so the back-projection of a pixel centre with its
depth lies exactly on the rendered (flat-triangle) surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

#: Triangles with a vertex closer than this to the camera plane are skipped, metres.
NEAR_M = 0.05


def clipped_in_view(verts_cam: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> bool:
    """Whether the renderer leaves out cloth that the camera would see: a vertex (N, 3) camera
    coordinates, metres, in front of the camera but closer than NEAR_M to its image plane, that
    projects into the (H, W) image (K (3, 3), pixels). Its triangles are not drawn, so the frame shows
    what lies behind them (a hole in the cloth, or its back side when the cloth reaches the camera)."""
    verts = np.asarray(verts_cam, dtype=np.float64).reshape(-1, 3)
    near = verts[(verts[:, 2] > 0) & (verts[:, 2] < NEAR_M)]
    if not len(near):
        return False
    x = K[0, 0] * near[:, 0] / near[:, 2] + K[0, 2]
    y = K[1, 1] * near[:, 1] / near[:, 2] + K[1, 2]
    H, W = size
    return bool(((x > -0.5) & (x < W - 0.5) & (y > -0.5) & (y < H - 0.5)).any())


@dataclass
class RenderOutput:
    """One rendered view.

    Attributes:
        color: (H, W, 3) float32 BGR in [0, 1] (noise-free, background 0).
        depth: (H, W) float32 camera depth Z in metres, 0 on background.
        uv: (H, W, 2) float32 cloth surface coordinates (u, v) in metres, -1 on background.
        cos_view: (H, W) float32 |cos| of the angle between the surface normal and the viewing ray
            (0 on background), used by the depth-noise model.
    """

    color: np.ndarray
    depth: np.ndarray
    uv: np.ndarray
    cos_view: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels on the cloth."""
        return self.depth > 0


@njit(cache=True)
def _rasterize(verts, tris, fx, fy, cx, cy, height, width, near):
    zbuf = np.zeros((height, width), dtype=np.float64)
    tri_id = np.full((height, width), -1, dtype=np.int32)
    bary = np.zeros((height, width, 2), dtype=np.float64)
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        za = verts[a, 2]
        zb = verts[b, 2]
        zc = verts[c, 2]
        if za < near or zb < near or zc < near:
            continue
        xa = fx * verts[a, 0] / za + cx
        ya = fy * verts[a, 1] / za + cy
        xb = fx * verts[b, 0] / zb + cx
        yb = fy * verts[b, 1] / zb + cy
        xc = fx * verts[c, 0] / zc + cx
        yc = fy * verts[c, 1] / zc + cy
        area = (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya)
        if abs(area) < 1e-12:
            continue
        x0 = max(int(np.ceil(min(xa, min(xb, xc)))), 0)
        x1 = min(int(np.floor(max(xa, max(xb, xc)))), width - 1)
        y0 = max(int(np.ceil(min(ya, min(yb, yc)))), 0)
        y1 = min(int(np.floor(max(ya, max(yb, yc)))), height - 1)
        inv_area = 1.0 / area
        for py in range(y0, y1 + 1):
            for px in range(x0, x1 + 1):
                w0 = ((xb - px) * (yc - py) - (xc - px) * (yb - py)) * inv_area
                w1 = ((xc - px) * (ya - py) - (xa - px) * (yc - py)) * inv_area
                w2 = 1.0 - w0 - w1
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                inv_z = w0 / za + w1 / zb + w2 / zc
                z = 1.0 / inv_z
                if tri_id[py, px] < 0 or z < zbuf[py, px]:
                    zbuf[py, px] = z
                    tri_id[py, px] = t
                    bary[py, px, 0] = w0 / za * z
                    bary[py, px, 1] = w1 / zb * z
    return zbuf, tri_id, bary


@njit(cache=True, parallel=True)
def _shade(zbuf, tri_id, bary, tris, uv_verts, normals, texture, tex_scale_u, tex_scale_v,
           lights, light_power, ambient, fx, fy, cx, cy, specular, shininess, back_color):
    height, width = zbuf.shape
    th, tw = texture.shape[0], texture.shape[1]
    color = np.zeros((height, width, 3), dtype=np.float32)
    depth = np.zeros((height, width), dtype=np.float32)
    uv = np.full((height, width, 2), -1.0, dtype=np.float32)
    cos_view = np.zeros((height, width), dtype=np.float32)
    for py in prange(height):
        for px in range(width):
            t = tri_id[py, px]
            if t < 0:
                continue
            z = zbuf[py, px]
            b0 = bary[py, px, 0]
            b1 = bary[py, px, 1]
            b2 = 1.0 - b0 - b1
            a = tris[t, 0]
            b = tris[t, 1]
            c = tris[t, 2]
            u = b0 * uv_verts[a, 0] + b1 * uv_verts[b, 0] + b2 * uv_verts[c, 0]
            v = b0 * uv_verts[a, 1] + b1 * uv_verts[b, 1] + b2 * uv_verts[c, 1]
            # surface point and normal (camera frame), normal turned towards the camera
            X = (px - cx) / fx * z
            Y = (py - cy) / fy * z
            nx = b0 * normals[a, 0] + b1 * normals[b, 0] + b2 * normals[c, 0]
            ny = b0 * normals[a, 1] + b1 * normals[b, 1] + b2 * normals[c, 1]
            nz = b0 * normals[a, 2] + b1 * normals[b, 2] + b2 * normals[c, 2]
            nn = np.sqrt(nx * nx + ny * ny + nz * nz) + 1e-12
            nx /= nn
            ny /= nn
            nz /= nn
            rn = np.sqrt(X * X + Y * Y + z * z)
            cv = (nx * X + ny * Y + nz * z) / rn
            back = cv < 0  # the normal du x dv points away from the side seen in the reference
            if cv > 0:
                nx = -nx
                ny = -ny
                nz = -nz
                cv = -cv
            shade = ambient
            spec = 0.0
            for li in range(lights.shape[0]):
                lx = lights[li, 0] - X
                ly = lights[li, 1] - Y
                lz = lights[li, 2] - z
                ln = np.sqrt(lx * lx + ly * ly + lz * lz) + 1e-12
                d = (nx * lx + ny * ly + nz * lz) / ln
                if d > 0:
                    shade += light_power[li] * d
                    if specular > 0:
                        # Blinn-Phong: half vector of the light and the view direction (-X, -Y, -z)
                        hx = lx / ln - X / rn
                        hy = ly / ln - Y / rn
                        hz = lz / ln - z / rn
                        hn = np.sqrt(hx * hx + hy * hy + hz * hz) + 1e-12
                        nh = (nx * hx + ny * hy + nz * hz) / hn
                        if nh > 0:
                            spec += specular * light_power[li] * nh ** shininess
            # bilinear texture lookup (clamped)
            tx = min(max(u * tex_scale_u, 0.0), tw - 1.0)
            ty = min(max(v * tex_scale_v, 0.0), th - 1.0)
            ix = min(int(tx), tw - 2)
            iy = min(int(ty), th - 2)
            fxr = tx - ix
            fyr = ty - iy
            for k in range(3):
                if back and back_color[0] >= 0:
                    col = back_color[k]
                else:
                    col = (texture[iy, ix, k] * (1 - fxr) * (1 - fyr) + texture[iy, ix + 1, k] * fxr * (1 - fyr)
                           + texture[iy + 1, ix, k] * (1 - fxr) * fyr + texture[iy + 1, ix + 1, k] * fxr * fyr)
                color[py, px, k] = min(col * shade + spec, 1.0)
            depth[py, px] = z
            uv[py, px, 0] = u
            uv[py, px, 1] = v
            cos_view[py, px] = -cv
    return color, depth, uv, cos_view


def render(
    verts_cam: np.ndarray,
    normals_cam: np.ndarray,
    uv_verts: np.ndarray,
    triangles: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    texture: np.ndarray,
    cloth_size_m: tuple[float, float],
    lights_cam: np.ndarray | None = None,
    light_power: np.ndarray | None = None,
    ambient: float = 0.3,
    specular: float = 0.0,
    shininess: float = 20.0,
    back_color: np.ndarray | None = None,
) -> RenderOutput:
    """Rasterise the textured cloth, lit diffusely (plus an optional Blinn-Phong highlight).

    Args:
        verts_cam: (N, 3) vertex positions in camera coordinates, metres.
        normals_cam: (N, 3) unit vertex normals in camera coordinates (either side).
        uv_verts: (N, 2) surface coordinates of the vertices, metres.
        triangles: (T, 3) int32 vertex indices.
        K: (3, 3) intrinsics, pixels.
        size: (H, W) of the image, pixels.
        texture: (Ht, Wt, 3) float32 BGR albedo in [0, 1]; u in [0, cloth_w] maps to x in [0, Wt - 1],
            v in [0, cloth_h] to y in [0, Ht - 1].
        cloth_size_m: (cloth_w, cloth_h) rest size in metres.
        lights_cam: (L, 3) point-light positions in camera coordinates, metres (default: one at the camera).
        light_power: (L,) diffuse strengths (default 0.7).
        ambient: ambient term added to the diffuse shading.
        specular: strength of a white Blinn-Phong highlight per light (0 = matte).
        shininess: Blinn-Phong exponent (larger = smaller, sharper highlights).
        back_color: (3,) BGR albedo in [0, 1] of the cloth's back side (the side facing away from
            the camera in the reference); None = the back shows the texture too.
    """
    H, W = size
    if lights_cam is None:
        lights_cam = np.zeros((1, 3))
    if light_power is None:
        light_power = np.full(len(lights_cam), 0.7)
    verts_cam = np.ascontiguousarray(verts_cam, dtype=np.float64)
    tris = np.ascontiguousarray(triangles, dtype=np.int32)
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    zbuf, tri_id, bary = _rasterize(verts_cam, tris, fx, fy, cx, cy, int(H), int(W), NEAR_M)
    texture = np.ascontiguousarray(texture, dtype=np.float32)
    th, tw = texture.shape[:2]
    color, depth, uv, cos_view = _shade(
        zbuf, tri_id, bary, tris, np.ascontiguousarray(uv_verts, dtype=np.float64),
        np.ascontiguousarray(normals_cam, dtype=np.float64), texture,
        (tw - 1) / cloth_size_m[0], (th - 1) / cloth_size_m[1],
        np.ascontiguousarray(lights_cam, dtype=np.float64).reshape(-1, 3),
        np.ascontiguousarray(light_power, dtype=np.float64).ravel(), float(ambient), fx, fy, cx, cy,
        float(specular), float(shininess),
        np.full(3, -1.0) if back_color is None else np.asarray(back_color, dtype=np.float64).reshape(3),
    )
    return RenderOutput(color=color, depth=depth, uv=uv, cos_view=cos_view)
