"""Straightest geodesics on the implicit grid mesh (numba kernels).

From a start point inside a face, a ray goes straight inside the face until it meets an edge, then
continues into the neighbouring face with its direction unfolded across the shared edge (rotated
about the edge by the dihedral angle, so that the two faces laid flat show a straight line). The
accumulated 3D arc length gives exact geodesic sample positions along the ray.

The walk runs in intrinsic 2D coordinates: each face has its own planar frame (`face_frames`), a ray
is a 2D point and direction in the current face, and crossing an edge re-expresses both in the
neighbour's frame by the 2D rotation that maps the shared edge onto itself, which is the same as
rotating the 3D direction about the edge by the dihedral angle. 3D points are rebuilt only where
samples are emitted.

Face addressing follows `geofeat.geodesic.mesh`: face (x, y, t) is triangle t of grid cell (x, y).
Local vertex order: face 0 = (a, b, c), face 1 = (d, b, c) with a = (x, y), b = (x + 1, y),
c = (x, y + 1), d = (x + 1, y + 1). Local edge e is the edge opposite local vertex e.

One kernel source for CPU and GPU: the scalar helpers and the per-keypoint / per-ray bodies
(`_tangent_frame_one`, `_ray_one`) are plain Python functions written with `math` only. They are
compiled here by `numba.njit` (the CPU path: `tangent_frames`, `walk_polar`) and by
`numba.cuda.jit(device=True)` in `geofeat.geodesic.walk_cuda` (the GPU path, imported only on
demand), which recompiles the same code objects with the helper names bound to their CUDA versions
(`DEVICE_SOURCES`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: Plain-Python sources of the functions shared by the CPU and GPU walks, by name (filled by `_shared`).
DEVICE_SOURCES: dict = {}


def _shared(inline: bool = True):
    """Compile a shared source for the CPU (njit, as before the GPU path existed) and keep the
    plain function in `DEVICE_SOURCES` for `walk_cuda`."""
    def wrap(fn):
        DEVICE_SOURCES[fn.__name__] = fn
        if inline:
            return njit(cache=True, inline="always", error_model="numpy")(fn)
        return njit(cache=True, error_model="numpy")(fn)
    return wrap

#: Upper bound on edge crossings of one ray; a ray that hits it stops where it is.
MAX_CROSSINGS = 100_000


@_shared()
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@_shared()
def _corner(x, y, t, i):
    """Grid (column, row) of local vertex i of face (x, y, t)."""
    if i == 0:
        if t == 0:
            return x, y
        return x + 1, y + 1
    if i == 1:
        return x + 1, y
    return x, y + 1


@_shared(inline=False)
def _neighbour(x, y, t, e):
    """Face across local edge e of face (x, y, t), and the local index of that edge there."""
    if e == 0:
        return x, y, 1 - t, 0
    if t == 0:
        if e == 1:
            return x - 1, y, 1, 2  # left edge a-c -> right edge d-b of the cell on the left
        return x, y - 1, 1, 1  # top edge a-b -> bottom edge d-c of the cell above
    if e == 1:
        return x, y + 1, 0, 2  # bottom edge d-c -> top edge a-b of the cell below
    return x + 1, y, 0, 1  # right edge d-b -> left edge a-c of the cell on the right


@_shared()
def _edge_vertices(e):
    """Local vertices (i0, i1) at the ends of local edge e (the edge opposite vertex e)."""
    return (1 if e == 0 else 0), (1 if e == 2 else 2)


def _swap_table() -> np.ndarray:
    """(2, 3) bool: whether the edge shared with the neighbour across local edge e of a face of type
    t runs the other way in the neighbour's `_edge_vertices` order (fixed by the grid layout)."""
    table = np.zeros((2, 3), np.bool_)
    for t in range(2):
        for e in range(3):
            xn, yn, tn, en = _neighbour(5, 5, t, e)
            g0 = _corner(5, 5, t, _edge_vertices(e)[0])
            table[t, e] = _corner(xn, yn, tn, _edge_vertices(en)[0]) != g0
    return table


#: `_swap_table()`, written out (a test checks it against the grid layout).
_SWAP = np.array([[False, True, True], [False, True, True]])


@_shared()
def _face_axes(points, normals, x, y, t):
    """Intrinsic frame of face (x, y, t): origin (local vertex 0), unit x axis (towards local vertex
    1), unit y axis (normal x x axis), and the length of the edge from vertex 0 to vertex 1."""
    x0, y0 = _corner(x, y, t, 0)
    ax, ay, az = points[y0, x0, 0], points[y0, x0, 1], points[y0, x0, 2]
    ex, ey, ez = points[y, x + 1, 0] - ax, points[y, x + 1, 1] - ay, points[y, x + 1, 2] - az
    length = math.sqrt(ex * ex + ey * ey + ez * ez)
    ex, ey, ez = ex / length, ey / length, ez / length
    fx, fy, fz = _cross(normals[y, x, t, 0], normals[y, x, t, 1], normals[y, x, t, 2], ex, ey, ez)
    return ax, ay, az, ex, ey, ez, fx, fy, fz, length


@_shared()
def _face_frame_one(points, face_ok, normals, out, x, y, t):
    """out[y, x, t] = [|v1 - v0|, v2.x, v2.y] of face (x, y, t) (see `face_frames`); nothing for a
    missing face. The same source runs as a CUDA thread (`walk_cuda.mesh_faces_cuda`)."""
    if not face_ok[y, x, t]:
        return
    ax, ay, az, ex, ey, ez, fx, fy, fz, length = _face_axes(points, normals, x, y, t)
    wx, wy, wz = points[y + 1, x, 0] - ax, points[y + 1, x, 1] - ay, points[y + 1, x, 2] - az
    out[y, x, t, 0] = length
    out[y, x, t, 1] = wx * ex + wy * ey + wz * ez
    out[y, x, t, 2] = wx * fx + wy * fy + wz * fz


@njit(cache=True, parallel=True, error_model="numpy")
def face_frames(points, face_ok, normals):
    """Intrinsic 2D coordinates of every face: local vertex 0 at the origin, vertex 1 on the +x
    axis, y = normal x (+x). Returns (Hm - 1, Wm - 1, 2, 3) float64 [|v1 - v0|, v2.x, v2.y]."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    out = np.zeros((Hc, Wc, 2, 3))
    for row in prange(Hc):
        y = np.int64(row)
        for x in range(Wc):
            for t in range(2):
                _face_frame_one(points, face_ok, normals, out, x, y, t)
    return out


@_shared()
def _edge_directions_one(frames, face_ok, out, x, y, t):
    """out[y, x, t, e] = unit direction of local edge e of face (x, y, t) for e = 0, 1, 2 (see
    `edge_directions`); nothing for a missing face."""
    if not face_ok[y, x, t]:
        return
    for e in range(3):
        i0, i1 = _edge_vertices(e)
        ax, ay = _local(frames, x, y, t, i0)
        bx, by = _local(frames, x, y, t, i1)
        ex, ey = bx - ax, by - ay
        norm = math.sqrt(ex * ex + ey * ey)
        out[y, x, t, e, 0] = ex / norm
        out[y, x, t, e, 1] = ey / norm


@njit(cache=True, parallel=True, error_model="numpy")
def edge_directions(frames, face_ok):
    """Unit direction of every local edge in its face's intrinsic frame (see `face_frames`), from
    its first end to its second (`_edge_vertices` order). Returns (Hm - 1, Wm - 1, 2, 3, 2) float64.
    Crossing an edge, the walk's 2D rotation into the neighbour's frame is the rotation between the
    edge's direction on both sides, two products with these tables (edge unfolding precomputed)."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    out = np.zeros((Hc, Wc, 2, 3, 2))
    for row in prange(Hc):
        y = np.int64(row)
        for x in range(Wc):
            for t in range(2):
                _edge_directions_one(frames, face_ok, out, x, y, t)
    return out


@_shared()
def _local(frames, x, y, t, i):
    """2D coordinates of local vertex i of face (x, y, t) in the face's intrinsic frame."""
    if i == 0:
        return 0.0, 0.0
    if i == 1:
        return frames[y, x, t, 0], 0.0
    return frames[y, x, t, 1], frames[y, x, t, 2]


@_shared()
def _emit(points, frames, x, y, t, qx, qy, K, samples, coords, k, r, a):
    """Write the sample at intrinsic coordinates (qx, qy) of face (x, y, t): its 3D point (the
    barycentric combination of the face's corners) into samples[k, r, a] and its projection with K
    into coords[k, r, a]."""
    length, vx, vy = frames[y, x, t, 0], frames[y, x, t, 1], frames[y, x, t, 2]
    w2 = qy / vy
    w1 = (qx - w2 * vx) / length
    x0, y0 = _corner(x, y, t, 0)
    ax, ay, az = points[y0, x0, 0], points[y0, x0, 1], points[y0, x0, 2]
    X = ax + w1 * (points[y, x + 1, 0] - ax) + w2 * (points[y + 1, x, 0] - ax)
    Y = ay + w1 * (points[y, x + 1, 1] - ay) + w2 * (points[y + 1, x, 1] - ay)
    Z = az + w1 * (points[y, x + 1, 2] - az) + w2 * (points[y + 1, x, 2] - az)
    samples[k, r, a, 0], samples[k, r, a, 1], samples[k, r, a, 2] = X, Y, Z
    # project the stored (float32) point, so that coords are those of samples exactly
    X, Y, Z = float(samples[k, r, a, 0]), float(samples[k, r, a, 1]), float(samples[k, r, a, 2])
    coords[k, r, a, 0] = K[0, 0] * X / Z + K[0, 1] * Y / Z + K[0, 2]
    coords[k, r, a, 1] = K[1, 1] * Y / Z + K[1, 2]


@_shared()
def _edge_hit(frames, x, y, t, e, px, py, dx, dy):
    """Where the line (px, py) + u (dx, dy) meets local edge e of face (x, y, t): (u, s, ex, ey, ax, ay)
    with s the position along the edge from its first end (a) to its second (a + (ex, ey));
    u = s = NaN when parallel."""
    i0, i1 = _edge_vertices(e)
    ax, ay = _local(frames, x, y, t, i0)
    bx, by = _local(frames, x, y, t, i1)
    ex, ey = bx - ax, by - ay
    denom = dx * ey - dy * ex
    if abs(denom) < 1e-300:
        return math.nan, math.nan, ex, ey, ax, ay
    wx, wy = ax - px, ay - py
    return (wx * ey - wy * ex) / denom, (wx * dy - wy * dx) / denom, ex, ey, ax, ay


@_shared()
def _walk_one(points, face_ok, frames, edges, x, y, t, px, py, dx, dy, ring_step, n_rings, max_crossings,
              K, samples, coords, k, a):
    """Walk one ray on the mesh in intrinsic 2D coordinates.

    The ray starts at (px, py) in the intrinsic frame of face (x, y, t) (see `face_frames`), with
    unit direction (dx, dy) in that frame. Inside a face it is a straight 2D segment; crossing an
    edge, the position and direction are re-expressed in the neighbour's frame by the 2D rotation
    that maps the shared edge onto itself (this is the unfolding of the two triangles), read from
    the per-edge unit directions `edges` (see `edge_directions`).
    Writes the samples at arc lengths (i + 1) * ring_step, i < n_rings, into samples[k, :, a] (3D)
    and coords[k, :, a] (projected with K); rings beyond the end of the mesh repeat the last point
    reached. Returns the number of rings reached on the mesh."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    length = 0.0
    ring = 0
    entry = -1
    for _ in range(max_crossings):
        # exit edge, distance d to it and position s along it
        if entry < 0:  # start face: the nearest edge ahead of the ray
            exit_edge = -1
            d = math.inf
            s = 0.0
            for e in range(3):
                de, se, ex, ey, ax, ay = _edge_hit(frames, x, y, t, e, px, py, dx, dy)
                if de > 1e-15 and -1e-9 <= se <= 1.0 + 1e-9 and de < d:
                    exit_edge, d, s = e, de, se
                    fx, fy, gx, gy = ex, ey, ax, ay
            if exit_edge < 0:
                break
        else:
            # of the two other edges the ray leaves through the one it meets inside (the first
            # when both or neither are met inside); the second is only looked at when needed
            exit_edge = (entry + 1) % 3
            d, s, fx, fy, gx, gy = _edge_hit(frames, x, y, t, exit_edge, px, py, dx, dy)
            if not (-1e-12 <= s <= 1.0 + 1e-12):  # also when parallel (NaN)
                e = (entry + 2) % 3
                de, se, ex, ey, ax, ay = _edge_hit(frames, x, y, t, e, px, py, dx, dy)
                if -1e-12 <= se <= 1.0 + 1e-12 or math.isnan(s):
                    exit_edge, d, s, fx, fy, gx, gy = e, de, se, ex, ey, ax, ay
                if math.isnan(s):  # parallel to both edges
                    break
        if d < 0.0:
            d = 0.0
        # emit the rings that lie on this segment
        while ring < n_rings and length + d >= (ring + 1) * ring_step:
            r = (ring + 1) * ring_step - length
            _emit(points, frames, x, y, t, px + r * dx, py + r * dy, K, samples, coords, k, ring, a)
            ring += 1
        if ring == n_rings:
            return ring
        s = min(max(s, 0.0), 1.0)
        qx, qy = gx + s * fx, gy + s * fy
        length += math.sqrt((qx - px) ** 2 + (qy - py) ** 2)
        px, py = qx, qy
        xn, yn, tn, entry_n = _neighbour(x, y, t, exit_edge)
        if xn < 0 or yn < 0 or xn >= Wc or yn >= Hc or not face_ok[yn, xn, tn]:
            break
        # the shared edge in the neighbour's frame, oriented like ours (same grid end first)
        j0, j1 = _edge_vertices(entry_n)
        ux, uy = edges[y, x, t, exit_edge, 0], edges[y, x, t, exit_edge, 1]
        vx, vy = edges[yn, xn, tn, entry_n, 0], edges[yn, xn, tn, entry_n, 1]
        if _SWAP[t, exit_edge]:
            j0, j1 = j1, j0
            vx, vy = -vx, -vy
        cos_a = ux * vx + uy * vy
        sin_a = ux * vy - uy * vx
        dx, dy = cos_a * dx - sin_a * dy, sin_a * dx + cos_a * dy
        a2x, a2y = _local(frames, xn, yn, tn, j0)
        b2x, b2y = _local(frames, xn, yn, tn, j1)
        px, py = a2x + s * (b2x - a2x), a2y + s * (b2y - a2y)
        x, y, t, entry = xn, yn, tn, entry_n
    # the ray left the mesh: later rings repeat the last point reached
    for r in range(ring, n_rings):
        _emit(points, frames, x, y, t, px, py, K, samples, coords, k, r, a)
    return ring


@_shared()
def _rotate_onto(vx, vy, vz, ax, ay, az, bx, by, bz):
    """Rotate v by the smallest rotation that takes unit a to unit b (Rodrigues)."""
    kx, ky, kz = _cross(ax, ay, az, bx, by, bz)
    sin_a = math.sqrt(kx * kx + ky * ky + kz * kz)
    cos_a = ax * bx + ay * by + az * bz
    if sin_a < 1e-12:
        return vx, vy, vz
    kx, ky, kz = kx / sin_a, ky / sin_a, kz / sin_a
    cx, cy, cz = _cross(kx, ky, kz, vx, vy, vz)
    kv = (kx * vx + ky * vy + kz * vz) * (1 - cos_a)
    return vx * cos_a + cx * sin_a + kx * kv, vy * cos_a + cy * sin_a + ky * kv, vz * cos_a + cz * sin_a + kz * kv


@_shared(inline=False)
def _locate(face_ok, xm, ym):
    """Face (x, y, t) containing mesh pixel coordinates (xm, ym), and its barycentric weights
    (w_first, w_b, w_c) for local vertices (a or d, b, c). x = -1 when outside the grid."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    x = int(math.floor(xm))
    y = int(math.floor(ym))
    if x < 0 or y < 0 or x >= Wc or y >= Hc:
        return -1, -1, -1, 0.0, 0.0, 0.0
    fx = xm - x
    fy = ym - y
    if fx + fy <= 1.0:
        return x, y, 0, 1.0 - fx - fy, fx, fy
    return x, y, 1, fx + fy - 1.0, 1.0 - fy, 1.0 - fx


@_shared(inline=False)
def _tangent_frame_one(points, face_ok, normals, sx, sy, faces, centre, frames, k):
    """`tangent_frames` of one keypoint at mesh pixel (sx, sy): writes faces[k], centre[k] and
    frames[k] when the start has surface, leaves them untouched otherwise."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    x, y, t, w0, w1, w2 = _locate(face_ok, sx, sy)
    if x < 0 or not face_ok[y, x, t]:
        return
    xa, ya = _corner(x, y, t, 0)
    p0 = w0 * points[ya, xa, 0] + w1 * points[y, x + 1, 0] + w2 * points[y + 1, x, 0]
    p1 = w0 * points[ya, xa, 1] + w1 * points[y, x + 1, 1] + w2 * points[y + 1, x, 1]
    p2 = w0 * points[ya, xa, 2] + w1 * points[y, x + 1, 2] + w2 * points[y + 1, x, 2]
    # tangent plane normal: mean of the unit face normals around the start cell (not area-weighted)
    n0 = n1 = n2 = 0.0
    for yy in range(max(0, y - 1), min(Hc, y + 2)):
        for xx in range(max(0, x - 1), min(Wc, x + 2)):
            for tt in range(2):
                if face_ok[yy, xx, tt]:
                    n0 += normals[yy, xx, tt, 0]
                    n1 += normals[yy, xx, tt, 1]
                    n2 += normals[yy, xx, tt, 2]
    nl = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    n0, n1, n2 = n0 / nl, n1 / nl, n2 / nl
    # column 0: the direction in the tangent plane that moves along image +x, i.e. that is
    # orthogonal to the gradient of the image y coordinate, gv = (0, 1, -Y/Z) up to scale
    gvz = -p1 / p2
    guz = -p0 / p2
    e0x, e0y, e0z = _cross(n0, n1, n2, 0.0, 1.0, gvz)
    l0 = math.sqrt(e0x * e0x + e0y * e0y + e0z * e0z)
    if l0 < 1e-12:
        return  # surface seen exactly edge-on
    sign = 1.0 if e0x + e0z * guz >= 0 else -1.0
    e0x, e0y, e0z = sign * e0x / l0, sign * e0y / l0, sign * e0z / l0
    e1x, e1y, e1z = _cross(n0, n1, n2, e0x, e0y, e0z)
    sign = -1.0 if e1y + e1z * gvz > 0 else 1.0  # counter-clockwise as displayed: image up is -y
    frames[k, 0, 0], frames[k, 0, 1], frames[k, 0, 2] = e0x, e0y, e0z
    frames[k, 1, 0], frames[k, 1, 1], frames[k, 1, 2] = sign * e1x, sign * e1y, sign * e1z
    centre[k, 0], centre[k, 1], centre[k, 2] = p0, p1, p2
    frames[k, 2, 0], frames[k, 2, 1], frames[k, 2, 2] = n0, n1, n2
    faces[k, 0], faces[k, 1], faces[k, 2] = x, y, t


# Not inlined into `walk_polar_in_order`: numba's parallel pass then works on a small loop body
# that calls one compiled function, which cut the walk's first compile from 56 s to 17 s on the
# development machine (the helpers are still inlined into `_ray_one`; same results bit for bit,
# same walk time: BENCHMARKS.md, "The walk's first compile").
@_shared(inline=False)
def _ray_one(points, face_ok, normals, local, edges, faces, centre, frames, K, ring_step, n_angles, n_rings,
             max_crossings, samples, coords, k, a):
    """The ray of keypoint k at direction a (`walk_polar`, one job): returns the rings reached, -1
    when the keypoint has no surface (then nothing is written)."""
    if faces[k, 0] < 0:  # no surface under the keypoint
        return -1
    x, y, t = faces[k, 0], faces[k, 1], faces[k, 2]
    theta = 2.0 * math.pi * a / n_angles
    c, sn = math.cos(theta), math.sin(theta)
    dx = c * frames[k, 0, 0] + sn * frames[k, 1, 0]
    dy = c * frames[k, 0, 1] + sn * frames[k, 1, 1]
    dz = c * frames[k, 0, 2] + sn * frames[k, 1, 2]
    fnx, fny, fnz = normals[y, x, t, 0], normals[y, x, t, 1], normals[y, x, t, 2]
    ux, uy, uz = _rotate_onto(dx, dy, dz, frames[k, 2, 0], frames[k, 2, 1], frames[k, 2, 2], fnx, fny, fnz)
    # start point and direction in the start face's intrinsic frame
    ax, ay, az, ex, ey, ez, fx, fy, fz, _ = _face_axes(points, normals, x, y, t)
    cx, cy, cz = centre[k, 0] - ax, centre[k, 1] - ay, centre[k, 2] - az
    dxx, dyy = ux * ex + uy * ey + uz * ez, ux * fx + uy * fy + uz * fz
    dl = math.sqrt(dxx * dxx + dyy * dyy)
    return _walk_one(points, face_ok, local, edges, x, y, t, cx * ex + cy * ey + cz * ez,
                     cx * fx + cy * fy + cz * fz, dxx / dl, dyy / dl, ring_step, n_rings,
                     max_crossings, K, samples, coords, k, a)


@njit(cache=True, parallel=True, error_model="numpy")
def tangent_frames(points, face_ok, normals, starts):
    """Start face, start point and tangent frame of every keypoint.

    Args:
        points, face_ok, normals: see `GridMesh`.
        starts: (N, 2) float64 mesh pixel coordinates.
    Returns:
        faces (N, 3) int64 (x, y, t) of the start face, -1 where the start has no surface;
        centre (N, 3) float64 start point, metres (NaN without surface);
        frames (N, 3, 3) float64 rows e0, e1, n: e0 is image +x projected onto the tangent plane,
        e1 turns counter-clockwise as displayed, n the mean unit normal of the faces around the start cell.
    """
    N = starts.shape[0]
    centre = np.full((N, 3), np.nan)
    frames = np.zeros((N, 3, 3))  # per keypoint: e0, e1, normal of the start face
    faces = np.full((N, 3), -1, dtype=np.int64)
    for k in prange(N):
        _tangent_frame_one(points, face_ok, normals, starts[k, 0], starts[k, 1], faces, centre, frames, k)
    return faces, centre, frames


#: Keypoints are walked in bands of this many mesh rows, left to right in each band (`walk_order`).
WALK_BAND_PX = 16


@njit(cache=True)
def walk_order(starts, band_px=WALK_BAND_PX):
    """(N,) int64: the order in which `walk_polar` walks the keypoints at (N, 2) mesh pixel `starts`:
    by bands of `band_px` mesh rows from the top, left to right in each band (ties keep their
    order). Nearby keypoints' rays cross the same faces, so walked one after another they find the
    mesh tables in the cache: on the Kinect frame's 2048 keypoints this took 5-22 % off the walk
    (BENCHMARKS.md). The order changes no result: every ray is independent and writes its own slot."""
    key = np.floor(starts[:, 1] / band_px) * 1e7 + starts[:, 0]
    return np.argsort(key, kind="mergesort")


@njit(cache=True)
def walk_polar(points, face_ok, normals, local, edges, starts, K, radius, n_angles, n_rings, max_crossings):
    """Geodesic polar samples around many start points, one ray per (keypoint, direction) in
    parallel, the keypoints walked in `walk_order` (`walk_polar_in_order`).

    Args:
        points: (Hm, Wm, 3) float64 mesh vertices, metres.
        face_ok, normals: see `GridMesh`.
        local, edges: `face_frames(points, face_ok, normals)` and `edge_directions(local, face_ok)`
            (per-face data of the walk, built once per mesh: `GridMesh.walk_tables`).
        starts: (N, 2) float64 mesh pixel coordinates of the keypoints.
        K: (3, 3) intrinsics of the image that samples are projected into.
        radius: geodesic radius of the outer ring, metres.
    Returns:
        samples (N, n_rings, n_angles, 3) float32 metres, coords (N, n_rings, n_angles, 2) float32
        image pixels (x, y) of the samples projected with K, reached (N, n_angles) int32 rings
        reached per direction, centre (N, 3) float64 start point (NaN when the start has no face).
    """
    return walk_polar_in_order(points, face_ok, normals, local, edges, starts, K, radius, n_angles, n_rings,
                               max_crossings, walk_order(starts))


@njit(cache=True, parallel=True, error_model="numpy")
def walk_polar_in_order(points, face_ok, normals, local, edges, starts, K, radius, n_angles, n_rings, max_crossings,
                        order):
    """`walk_polar`, walking the keypoints in the (N,) int64 `order` (a permutation of 0..N-1; the
    results are the same for every order, only the time differs: `benchmarks/bench_walk_order.py`)."""
    N = starts.shape[0]
    seen = np.zeros(N, np.bool_)
    if order.shape[0] != N:
        raise ValueError("order: expected a permutation of the keypoints")
    for k in order:  # a repeated keypoint would leave another's samples unwritten (np.empty)
        if k < 0 or k >= N or seen[k]:
            raise ValueError("order: expected a permutation of the keypoints")
        seen[k] = True
    samples = np.empty((N, n_rings, n_angles, 3), dtype=np.float32)  # every entry is written below
    coords = np.empty((N, n_rings, n_angles, 2), dtype=np.float32)
    reached = np.zeros((N, n_angles), dtype=np.int32)
    faces, centre, frames = tangent_frames(points, face_ok, normals, starts)
    ring_step = radius / n_rings
    for job in prange(N * n_angles):
        k = order[job // n_angles]
        a = job % n_angles
        r = _ray_one(points, face_ok, normals, local, edges, faces, centre, frames, K, ring_step, n_angles,
                     n_rings, max_crossings, samples, coords, k, a)
        if r < 0:  # no surface under the keypoint
            samples[k, :, a, :] = np.nan
            coords[k, :, a, :] = np.nan
        else:
            reached[k, a] = r
    return samples, coords, reached, centre
