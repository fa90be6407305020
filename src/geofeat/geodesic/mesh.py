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

import math
import zlib
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit, prange

from ..constants import MAX_EDGE_STRETCH
from ..depth import DepthConfig, backproject, mean_focal, preprocess_depth, resolve_depth_config, scale_intrinsics
from ..frame import RGBDFrame, check_depth, check_frame, check_intrinsics
from ..inputs import check_positive
from .walk import _shared


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
        source: `frame_fingerprint` of that frame (depth and intrinsics), None when unknown; a mesh
            given to `polar_patches` must come from the frame it describes.
        config: the `DepthConfig` its depth was preprocessed with (a profile name resolved on the
            frame), None when unknown; polar patches walked on it record it (`PolarPatches.depth_config`).
    """

    points: np.ndarray
    face_ok: np.ndarray
    normals: np.ndarray
    K: np.ndarray
    scale: tuple[float, float]
    image_shape: tuple[int, int]
    source: tuple | None = field(default=None, repr=False, compare=False)
    config: DepthConfig | None = field(default=None, repr=False, compare=False)

    @cached_property
    def walk_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-face data of the geodesic walk, built on first use and kept with the mesh:
        (Hm - 1, Wm - 1, 2, 3) intrinsic corner coordinates (`walk.face_frames`) and
        (Hm - 1, Wm - 1, 2, 3, 2) unit edge directions (`walk.edge_directions`)."""
        from .walk import edge_directions, face_frames

        local = face_frames(self.points, self.face_ok, self.normals)
        return local, edge_directions(local, self.face_ok)

    def image_to_mesh(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) image pixel coordinates -> (N, 2) mesh pixel coordinates."""
        return image_to_mesh(xy, self.scale)

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


def image_to_mesh(xy: np.ndarray, scale: tuple[float, float]) -> np.ndarray:
    """(N, 2) image pixel coordinates -> (N, 2) coordinates on a mesh grid of `scale` = (sx, sy)
    mesh pixels per image pixel (pixel centres kept consistent, as `depth.scale_intrinsics`)."""
    xy = np.asarray(xy, dtype=np.float64)
    sx, sy = scale
    return np.stack([(xy[:, 0] + 0.5) * sx - 0.5, (xy[:, 1] + 0.5) * sy - 0.5], axis=1)


@_shared()
def _face_one(points, fx, max_edge_stretch, ok, normals, x, y, t):
    """Decide whether face (x, y, t) exists and write ok[y, x, t] and its unit normal towards the
    camera into normals[y, x, t] (both left untouched, False / 0, when it does not). One face of
    `_faces`; the same source runs as a CUDA thread (`walk_cuda.mesh_faces_cuda`)."""
    # corners: face 0 = (a, b, c), face 1 = (d, b, c); a=(x,y) b=(x+1,y) c=(x,y+1) d=(x+1,y+1)
    py, px = (y, x) if t == 0 else (y + 1, x + 1)
    p0, p1, p2 = points[py, px, 0], points[py, px, 1], points[py, px, 2]
    q0, q1, q2 = points[y, x + 1, 0], points[y, x + 1, 1], points[y, x + 1, 2]
    r0, r1, r2 = points[y + 1, x, 0], points[y + 1, x, 1], points[y + 1, x, 2]
    if not (math.isfinite(p2) and math.isfinite(q2) and math.isfinite(r2)):
        return
    ux, uy, uz = q0 - p0, q1 - p1, q2 - p2
    vx, vy, vz = r0 - p0, r1 - p1, r2 - p2
    wx, wy, wz = r0 - q0, r1 - q1, r2 - q2
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not length > 0:
        return
    cz = (p2 + q2 + r2) / 3.0
    longest = max(ux * ux + uy * uy + uz * uz, vx * vx + vy * vy + vz * vz, wx * wx + wy * wy + wz * wz)
    footprint = cz / fx  # lateral size of one mesh pixel, metres
    if longest > (max_edge_stretch * footprint) ** 2:
        return  # a depth discontinuity, not surface
    cx, cy = (p0 + q0 + r0) / 3.0, (p1 + q1 + r1) / 3.0
    if nx * cx + ny * cy + nz * cz > 0:
        length = -length
    ok[y, x, t] = True
    normals[y, x, t, 0] = nx / length
    normals[y, x, t, 1] = ny / length
    normals[y, x, t, 2] = nz / length


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
                _face_one(points, fx, max_edge_stretch, ok, normals, x, y, t)
    return ok, normals


def mesh_from_points(
    points: np.ndarray, K: np.ndarray, scale: tuple[float, float], image_shape: tuple[int, int],
    max_edge_stretch: float = MAX_EDGE_STRETCH, source: tuple | None = None, config: DepthConfig | None = None,
) -> GridMesh:
    """Build the GridMesh of an (Hm, Wm, 3) grid of camera-frame points (NaN = missing); `source`: the
    `frame_fingerprint` of the frame they come from, `config`: the DepthConfig that made the points'
    depth, when known."""
    # NaN kept every face across depth steps, a negative value acted as its absolute value, 0 cut all
    max_edge_stretch = check_positive(max_edge_stretch, "max_edge_stretch")
    points = np.ascontiguousarray(points, dtype=np.float64)
    face_ok, normals = _faces(points, mean_focal(K), max_edge_stretch)
    return GridMesh(points=points, face_ok=face_ok, normals=normals, K=K, scale=scale, image_shape=image_shape,
                    source=source, config=config)


def check_frame_arrays(frame: RGBDFrame) -> None:
    """The frame's depth and intrinsics are checked when the frame is made, and are read-only after
    it; a caller who turns that off can still edit them in place (`frame_mesh` notices such edits):
    check them again before a mesh is built from them (NaN, negative or millimetre depth: ValueError)."""
    check_frame(frame)
    check_depth(frame.depth, frame.shape)
    check_intrinsics(frame.K)


def build_mesh(frame: RGBDFrame, config: DepthConfig | str = "auto",
               max_edge_stretch: float = MAX_EDGE_STRETCH, fingerprint: tuple | None = None) -> GridMesh:
    """Preprocess the frame's depth (a `DepthConfig`, or a profile name: "auto", "kinect", "quantised",
    "clean"; see `geofeat.depth.depth_profile`) and build its GridMesh. `fingerprint`: the frame's
    `frame_fingerprint`, when the caller has just computed it (a CRC of the depth: 0.3 ms per 640 x 480)."""
    check_frame_arrays(frame)
    config = resolve_depth_config(config, frame)
    depth = preprocess_depth(frame.depth, config)
    H, W = frame.shape
    Hm, Wm = depth.shape
    scale = (Wm / W, Hm / H)
    K = scale_intrinsics(frame.K, *scale)
    source = fingerprint if fingerprint is not None else frame_fingerprint(frame)
    return mesh_from_points(backproject(depth, K), K, scale, (H, W), max_edge_stretch, source, config)


#: Attribute of an RGBDFrame under which `frame_mesh` keeps its meshes.
_CACHE_ATTR = "_geofeat_meshes"


def frame_fingerprint(frame: RGBDFrame) -> tuple:
    """What the mesh depends on besides the depth config: the depth values (CRC-32 of the bytes,
    so that an in-place edit of frame.depth is noticed) and the intrinsics. Meshes and polar patches
    keep their frame's (`source`), so that one of another frame is refused rather than used."""
    depth = np.ascontiguousarray(frame.depth)
    return depth.shape, zlib.crc32(depth), frame.K.tobytes()


def frame_depth_config(frame: RGBDFrame, config: DepthConfig | str, fingerprint: tuple | None = None) -> DepthConfig:
    """`resolve_depth_config(config, frame)`, a profile name's DepthConfig cached on the frame with
    its meshes (`frame_mesh`): "auto" measures the frame's depth once (a few ms), not on every call.
    `fingerprint`: the frame's `frame_fingerprint`, when already computed."""
    if not isinstance(config, str):
        return resolve_depth_config(config, frame)
    cache = frame.__dict__.setdefault(_CACHE_ATTR, {})
    fingerprint = fingerprint if fingerprint is not None else frame_fingerprint(frame)
    hit = cache.get(("profile", config))
    if hit is not None and hit[0] == fingerprint:
        return hit[1]
    resolved = resolve_depth_config(config, frame)
    cache[("profile", config)] = (fingerprint, resolved)
    return resolved


def frame_mesh(frame: RGBDFrame, config: DepthConfig | str = "auto",
               max_edge_stretch: float = MAX_EDGE_STRETCH, device=None):
    """`build_mesh(frame, config, max_edge_stretch)`, cached on the frame: a second call with the
    same depth config (e.g. a second `polar_patches` on the same frame) reuses the mesh and its walk
    tables; a changed depth (checked by checksum), intrinsics or config builds a new one. A profile
    name is resolved first ("auto" measures the frame), so "auto" and the profile it picks share.

    `device`: None or "cpu" for the host `GridMesh`; "cuda[:N]" for a `geofeat.gpu.DeviceMesh`, the
    same mesh and walk tables built on that GPU (`geofeat.gpu.build_mesh_cuda`), cached the same way."""
    from ..gpu import is_cuda_device  # a light module: torch and numba.cuda load only on use

    on_gpu = is_cuda_device(device)
    if device is not None and not on_gpu and str(device) != "cpu":
        raise ValueError(f"device: expected None, 'cpu' or 'cuda[:N]', got {device!r}")
    cache = frame.__dict__.setdefault(_CACHE_ATTR, {})
    fingerprint = frame_fingerprint(frame)
    config = frame_depth_config(frame, config, fingerprint)
    key = (config, float(max_edge_stretch)) + ((str(device),) if on_gpu else ())
    hit = cache.get(key)
    if hit is not None and hit[0] == fingerprint:
        return hit[1]
    if on_gpu:
        from ..gpu import build_mesh_cuda

        check_frame_arrays(frame)
        mesh = build_mesh_cuda(frame, config, max_edge_stretch, device=device, fingerprint=fingerprint)
    else:
        mesh = build_mesh(frame, config, max_edge_stretch, fingerprint=fingerprint)
    cache[key] = (fingerprint, mesh)
    return mesh
