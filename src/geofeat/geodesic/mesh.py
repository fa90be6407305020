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

from ..constants import MAX_EDGE_STRETCH
from ..depth import DepthConfig, backproject, preprocess_depth, scale_intrinsics
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


def face_vertices(points: np.ndarray) -> tuple[np.ndarray, ...]:
    """Corner points of both faces of every cell: returns (a, b, c, d), each (Hm-1, Wm-1, 3)."""
    return points[:-1, :-1], points[:-1, 1:], points[1:, :-1], points[1:, 1:]


def mesh_from_points(
    points: np.ndarray, K: np.ndarray, scale: tuple[float, float], image_shape: tuple[int, int],
    max_edge_stretch: float = MAX_EDGE_STRETCH,
) -> GridMesh:
    """Build the GridMesh of an (Hm, Wm, 3) grid of camera-frame points (NaN = missing)."""
    a, b, c, d = face_vertices(points)
    fx = 0.5 * (K[0, 0] + K[1, 1])
    with np.errstate(invalid="ignore"):
        n0 = np.cross(b - a, c - a)
        n1 = np.cross(c - d, b - d)
        faces = []
        normals = []
        for n, corners in ((n0, (a, b, c)), (n1, (d, b, c))):
            p, q, r = corners
            centroid = (p + q + r) / 3.0
            length = np.linalg.norm(n, axis=-1)
            ok = np.isfinite(length) & (length > 0)
            n = n / np.where(ok, length, 1.0)[..., None]
            flip = np.einsum("...i,...i->...", n, centroid) > 0
            n = np.where(flip[..., None], -n, n)
            footprint = centroid[..., 2] / fx  # lateral size of one mesh pixel, metres
            longest = np.maximum.reduce([
                np.linalg.norm(q - p, axis=-1), np.linalg.norm(r - q, axis=-1), np.linalg.norm(p - r, axis=-1)
            ])
            ok &= longest <= max_edge_stretch * footprint
            faces.append(ok)
            normals.append(np.where(ok[..., None], n, 0.0))
    return GridMesh(
        points=points,
        face_ok=np.stack(faces, axis=-1),
        normals=np.ascontiguousarray(np.stack(normals, axis=-2)),
        K=K,
        scale=scale,
        image_shape=image_shape,
    )


def build_mesh(frame: RGBDFrame, config: DepthConfig = DepthConfig(), max_edge_stretch: float = MAX_EDGE_STRETCH) -> GridMesh:
    """Preprocess the frame's depth (see `DepthConfig`) and build its GridMesh."""
    depth = preprocess_depth(frame.depth, config)
    H, W = frame.shape
    Hm, Wm = depth.shape
    scale = (Wm / W, Hm / H)
    K = scale_intrinsics(frame.K, *scale)
    return mesh_from_points(backproject(depth, K), K, scale, (H, W), max_edge_stretch)
