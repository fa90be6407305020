"""The implicit triangle mesh of a depth grid.

Vertex (x, y) of the mesh is the back-projected point of mesh pixel (x, y). Each grid cell (x, y)
holds two triangles with the diagonal from (x + 1, y) to (x, y + 1):

    face 0: a = (x, y),         b = (x + 1, y), c = (x, y + 1)
    face 1: d = (x + 1, y + 1), b = (x + 1, y), c = (x, y + 1)

A face exists when its three vertices have depth and it does not straddle a depth discontinuity
(an edge longer than `max_edge_stretch` times the lateral size of a mesh pixel at that depth).
Normals point towards the camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..constants import MAX_EDGE_STRETCH
from ..depth import DepthConfig, backproject, preprocess_depth, resolve_depth_config, scale_intrinsics
from ..frame import RGBDFrame


@dataclass(frozen=True)
class GridMesh:
    """Triangle mesh on a depth grid.

    Attributes:
        points: (Hm, Wm, 3) float64 camera-frame vertices in metres (NaN where missing).
        face_ok: (Hm - 1, Wm - 1, 2) bool, whether face t of cell (x, y) exists (index [y, x, t]).
        normals: (Hm - 1, Wm - 1, 2, 3) float64 unit face normals, towards the camera.
        K: (3, 3) intrinsics of the mesh grid (pixels of the mesh).
        scale: (sx, sy) mesh pixels per image pixel.
        image_shape: (H, W) of the frame the mesh was built from.
    """

    points: np.ndarray
    face_ok: np.ndarray
    normals: np.ndarray
    K: np.ndarray
    scale: tuple[float, float]
    image_shape: tuple[int, int]

    def image_to_mesh(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) image pixel coordinates -> (N, 2) mesh pixel coordinates."""
        xy = np.asarray(xy, dtype=np.float64)
        sx, sy = self.scale
        return np.stack([(xy[:, 0] + 0.5) * sx - 0.5, (xy[:, 1] + 0.5) * sy - 0.5], axis=1)

    def vertices_faces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Explicit mesh of the existing faces.

        Returns:
            V (n, 3) float64 metres, F (m, 3) int64 vertex indices (counter-clockwise seen from the
            camera), and index (Hm, Wm) int64 mapping a grid vertex to its row in V (-1 if unused).
        """
        Hm, Wm, _ = self.points.shape
        grid = np.arange(Hm * Wm).reshape(Hm, Wm)
        a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
        f0 = np.stack([a, c, b], axis=-1)[self.face_ok[:, :, 0]]
        f1 = np.stack([d, b, c], axis=-1)[self.face_ok[:, :, 1]]
        faces = np.concatenate([f0, f1])
        used = np.unique(faces)
        index = np.full(Hm * Wm, -1, dtype=np.int64)
        index[used] = np.arange(used.size)
        V = self.points.reshape(-1, 3)[used]
        return V, index[faces], index.reshape(Hm, Wm)


@njit(cache=True, parallel=True, error_model="numpy")
def _faces(points, fx, max_edge_stretch):
    """face_ok (Hm-1, Wm-1, 2) and unit normals (Hm-1, Wm-1, 2, 3) towards the camera, see GridMesh."""
    Hm, Wm = points.shape[0], points.shape[1]
    ok = np.zeros((Hm - 1, Wm - 1, 2), np.bool_)
    normals = np.zeros((Hm - 1, Wm - 1, 2, 3))
    for row in prange(Hm - 1):
        y = np.int64(row)
        for x in range(Wm - 1):
            for t in range(2):
                # corners: face 0 = (a, b, c), face 1 = (d, b, c); a=(x,y) b=(x+1,y) c=(x,y+1) d=(x+1,y+1)
                p = points[y, x] if t == 0 else points[y + 1, x + 1]
                q = points[y, x + 1]
                r = points[y + 1, x]
                if not (np.isfinite(p[2]) and np.isfinite(q[2]) and np.isfinite(r[2])):
                    continue
                ux, uy, uz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
                vx, vy, vz = r[0] - p[0], r[1] - p[1], r[2] - p[2]
                wx, wy, wz = r[0] - q[0], r[1] - q[1], r[2] - q[2]
                nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                length = np.sqrt(nx * nx + ny * ny + nz * nz)
                if not length > 0:
                    continue
                cz = (p[2] + q[2] + r[2]) / 3.0
                longest = max(ux * ux + uy * uy + uz * uz, vx * vx + vy * vy + vz * vz, wx * wx + wy * wy + wz * wz)
                footprint = cz / fx  # lateral size of one mesh pixel, metres
                if longest > (max_edge_stretch * footprint) ** 2:
                    continue  # a depth discontinuity, not surface
                cx, cy = (p[0] + q[0] + r[0]) / 3.0, (p[1] + q[1] + r[1]) / 3.0
                if nx * cx + ny * cy + nz * cz > 0:
                    length = -length
                ok[y, x, t] = True
                normals[y, x, t, 0] = nx / length
                normals[y, x, t, 1] = ny / length
                normals[y, x, t, 2] = nz / length
    return ok, normals


def mesh_from_points(
    points: np.ndarray, K: np.ndarray, scale: tuple[float, float], image_shape: tuple[int, int],
    max_edge_stretch: float = MAX_EDGE_STRETCH,
) -> GridMesh:
    """Build the GridMesh of an (Hm, Wm, 3) grid of camera-frame points (NaN = missing)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    face_ok, normals = _faces(points, 0.5 * (K[0, 0] + K[1, 1]), float(max_edge_stretch))
    return GridMesh(points=points, face_ok=face_ok, normals=normals, K=K, scale=scale, image_shape=image_shape)


def build_mesh(frame: RGBDFrame, config: DepthConfig | str = "auto",
               max_edge_stretch: float = MAX_EDGE_STRETCH) -> GridMesh:
    """Preprocess the frame's depth (a `DepthConfig`, or a profile name: "auto", "kinect", "clean";
    see `geofeat.depth.depth_profile`) and build its GridMesh."""
    depth = preprocess_depth(frame.depth, resolve_depth_config(config, frame))
    H, W = frame.shape
    Hm, Wm = depth.shape
    scale = (Wm / W, Hm / H)
    K = scale_intrinsics(frame.K, *scale)
    return mesh_from_points(backproject(depth, K), K, scale, (H, W), max_edge_stretch)
