"""Straightest geodesics on the implicit grid mesh (numba kernels).

From a start point inside a face, a ray goes straight inside the face until it meets an edge, then
continues into the neighbouring face with its direction unfolded across the shared edge (rotated
about the edge by the dihedral angle, so that the two faces laid flat show a straight line). The
accumulated 3D arc length gives exact geodesic sample positions along the ray.

Face addressing follows `geofeat.geodesic.mesh`: face (x, y, t) is triangle t of grid cell (x, y).
Local vertex order: face 0 = (a, b, c), face 1 = (d, b, c) with a = (x, y), b = (x + 1, y),
c = (x, y + 1), d = (x + 1, y + 1). Local edge e is the edge opposite local vertex e.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Upper bound on edge crossings of one ray; a ray that hits it stops where it is.
MAX_CROSSINGS = 100_000


@njit(cache=True, inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True)
def _corner(points, x, y, t, i):
    """Grid (column, row) of local vertex i of face (x, y, t)."""
    if i == 0:
        if t == 0:
            return x, y
        return x + 1, y + 1
    if i == 1:
        return x + 1, y
    return x, y + 1


@njit(cache=True)
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


@njit(cache=True)
def _edge_hit(points, x, y, t, e, p, u, n):
    """Intersection of the ray p + s u with local edge e of face (x, y, t), in the face plane.

    Returns (distance along the ray, edge parameter in [0, 1] from the lower local vertex).
    Distance is -1 when the ray is parallel to the edge."""
    i0 = 1 if e == 0 else 0
    i1 = 1 if e == 2 else 2
    x0, y0 = _corner(points, x, y, t, i0)
    x1, y1 = _corner(points, x, y, t, i1)
    P0 = points[y0, x0]
    ex = points[y1, x1, 0] - P0[0]
    ey = points[y1, x1, 1] - P0[1]
    ez = points[y1, x1, 2] - P0[2]
    c0, c1, c2 = _cross(u[0], u[1], u[2], ex, ey, ez)
    denom = c0 * n[0] + c1 * n[1] + c2 * n[2]
    if abs(denom) < 1e-18:
        return -1.0, 0.0
    wx, wy, wz = P0[0] - p[0], P0[1] - p[1], P0[2] - p[2]
    a0, a1, a2 = _cross(wx, wy, wz, ex, ey, ez)
    b0, b1, b2 = _cross(wx, wy, wz, u[0], u[1], u[2])
    dist = (a0 * n[0] + a1 * n[1] + a2 * n[2]) / denom
    s = (b0 * n[0] + b1 * n[1] + b2 * n[2]) / denom
    return dist, s


@njit(cache=True)
def _side(points, x, y, t, i, p, u, n):
    """Signed side of local vertex i relative to the ray (positive = left of u about n)."""
    vx, vy = _corner(points, x, y, t, i)
    q = points[vy, vx]
    c0, c1, c2 = _cross(u[0], u[1], u[2], q[0] - p[0], q[1] - p[1], q[2] - p[2])
    return c0 * n[0] + c1 * n[1] + c2 * n[2]


@njit(cache=True)
def _walk_one(points, face_ok, normals, x, y, t, p0, u0, ring_step, n_rings, out, max_crossings):
    """Walk one ray from point p0 (on face (x, y, t)) in direction u0 (unit, in that face's plane).

    Writes the 3D points at arc lengths (i + 1) * ring_step, i < n_rings, into out (n_rings, 3);
    rings beyond the end of the mesh repeat the last point reached. Returns the number of rings
    reached on the mesh."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    p = p0.copy()
    u = u0.copy()
    n = normals[y, x, t].copy()
    length = 0.0
    ring = 0
    entry = -1
    for _ in range(max_crossings):
        # choose the exit edge
        if entry < 0:
            best = -1
            best_d = np.inf
            best_s = 0.0
            for e in range(3):
                d, s = _edge_hit(points, x, y, t, e, p, u, n)
                if d > 1e-15 and -1e-9 <= s <= 1.0 + 1e-9 and d < best_d:
                    best, best_d, best_s = e, d, s
            if best < 0:
                break
            exit_edge, d, s = best, best_d, best_s
        else:
            # the exit is one of the two edges through the vertex opposite the entry edge
            i1 = 1 if entry == 0 else 0
            i2 = 1 if entry == 2 else 2
            side_r = _side(points, x, y, t, entry, p, u, n)
            side_1 = _side(points, x, y, t, i1, p, u, n)
            exit_edge = i2 if side_r * side_1 <= 0.0 else i1
            d, s = _edge_hit(points, x, y, t, exit_edge, p, u, n)
            if d < 0.0:
                d = 0.0
        # emit the rings that lie on this segment
        while ring < n_rings and length + d >= (ring + 1) * ring_step:
            r = (ring + 1) * ring_step - length
            for k in range(3):
                out[ring, k] = p[k] + r * u[k]
            ring += 1
        if ring == n_rings:
            return ring
        # move to the edge point (clamped onto the edge for robustness)
        if s < 0.0:
            s = 0.0
        elif s > 1.0:
            s = 1.0
        i0 = 1 if exit_edge == 0 else 0
        i1 = 1 if exit_edge == 2 else 2
        x0, y0 = _corner(points, x, y, t, i0)
        x1, y1 = _corner(points, x, y, t, i1)
        q = points[y0, x0] + s * (points[y1, x1] - points[y0, x0])
        step = np.sqrt(((q - p) ** 2).sum())
        length += step
        p = q
        # cross into the neighbouring face
        xn, yn, tn, entry_n = _neighbour(x, y, t, exit_edge)
        if xn < 0 or yn < 0 or xn >= Wc or yn >= Hc or not face_ok[yn, xn, tn]:
            break
        e = points[y1, x1] - points[y0, x0]
        e /= np.sqrt((e ** 2).sum())
        n2 = normals[yn, xn, tn]
        m1x, m1y, m1z = _cross(e[0], e[1], e[2], n[0], n[1], n[2])
        m2x, m2y, m2z = _cross(e[0], e[1], e[2], n2[0], n2[1], n2[2])
        along = u[0] * e[0] + u[1] * e[1] + u[2] * e[2]
        across = u[0] * m1x + u[1] * m1y + u[2] * m1z
        u[0] = along * e[0] + across * m2x
        u[1] = along * e[1] + across * m2y
        u[2] = along * e[2] + across * m2z
        u /= np.sqrt((u ** 2).sum())
        n = n2.copy()
        x, y, t, entry = xn, yn, tn, entry_n
    # the ray left the mesh: later rings repeat the last point reached
    for r in range(ring, n_rings):
        for k in range(3):
            out[r, k] = p[k]
    return ring


@njit(cache=True)
def _rotate_onto(v, n_from, n_to):
    """Rotate v by the smallest rotation that takes unit n_from to unit n_to (Rodrigues)."""
    kx, ky, kz = _cross(n_from[0], n_from[1], n_from[2], n_to[0], n_to[1], n_to[2])
    sin_a = np.sqrt(kx * kx + ky * ky + kz * kz)
    cos_a = n_from[0] * n_to[0] + n_from[1] * n_to[1] + n_from[2] * n_to[2]
    if sin_a < 1e-12:
        return v.copy()
    kx, ky, kz = kx / sin_a, ky / sin_a, kz / sin_a
    cx, cy, cz = _cross(kx, ky, kz, v[0], v[1], v[2])
    kv = kx * v[0] + ky * v[1] + kz * v[2]
    out = np.empty(3)
    out[0] = v[0] * cos_a + cx * sin_a + kx * kv * (1 - cos_a)
    out[1] = v[1] * cos_a + cy * sin_a + ky * kv * (1 - cos_a)
    out[2] = v[2] * cos_a + cz * sin_a + kz * kv * (1 - cos_a)
    return out


@njit(cache=True)
def _locate(face_ok, xm, ym):
    """Face (x, y, t) containing mesh pixel coordinates (xm, ym), and its barycentric weights
    (w_first, w_b, w_c) for local vertices (a or d, b, c). x = -1 when outside the grid."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    x = int(np.floor(xm))
    y = int(np.floor(ym))
    if x < 0 or y < 0 or x >= Wc or y >= Hc:
        return -1, -1, -1, 0.0, 0.0, 0.0
    fx = xm - x
    fy = ym - y
    if fx + fy <= 1.0:
        return x, y, 0, 1.0 - fx - fy, fx, fy
    return x, y, 1, fx + fy - 1.0, 1.0 - fy, 1.0 - fx


@njit(cache=True, parallel=True)
def walk_polar(points, face_ok, normals, starts, radius, n_angles, n_rings, max_crossings):
    """Geodesic polar samples around many start points.

    Args:
        points: (Hm, Wm, 3) float64 mesh vertices, metres.
        face_ok, normals: see `GridMesh`.
        starts: (N, 2) float64 mesh pixel coordinates of the keypoints.
        radius: geodesic radius of the outer ring, metres.
    Returns:
        samples (N, n_rings, n_angles, 3) float64 metres, reached (N, n_angles) int32 rings reached
        per direction, centre (N, 3) float64 start point (NaN when the start has no face).
    """
    N = starts.shape[0]
    samples = np.full((N, n_rings, n_angles, 3), np.nan)
    reached = np.zeros((N, n_angles), dtype=np.int32)
    centre = np.full((N, 3), np.nan)
    frames = np.zeros((N, 3, 3))  # per keypoint: e0, e1, normal of the start face
    faces = np.full((N, 3), -1, dtype=np.int64)
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    for k in prange(N):
        x, y, t, w0, w1, w2 = _locate(face_ok, starts[k, 0], starts[k, 1])
        if x < 0 or not face_ok[y, x, t]:
            continue
        xa, ya = _corner(points, x, y, t, 0)
        p = w0 * points[ya, xa] + w1 * points[y, x + 1] + w2 * points[y + 1, x]
        # tangent plane normal: area-weighted mean of the face normals around the start cell
        nrm = np.zeros(3)
        for yy in range(max(0, y - 1), min(Hc, y + 2)):
            for xx in range(max(0, x - 1), min(Wc, x + 2)):
                for tt in range(2):
                    if face_ok[yy, xx, tt]:
                        nrm += normals[yy, xx, tt]
        nrm /= np.sqrt((nrm ** 2).sum())
        # column 0: the direction in the tangent plane that moves along image +x, i.e. that is
        # orthogonal to the gradient of the image y coordinate, gv = (0, 1, -Y/Z) up to scale
        gvz = -p[1] / p[2]
        guz = -p[0] / p[2]
        e0x, e0y, e0z = _cross(nrm[0], nrm[1], nrm[2], 0.0, 1.0, gvz)
        l0 = np.sqrt(e0x * e0x + e0y * e0y + e0z * e0z)
        if l0 < 1e-12:
            continue  # surface seen exactly edge-on
        sign = 1.0 if e0x + e0z * guz >= 0 else -1.0
        e0x, e0y, e0z = sign * e0x / l0, sign * e0y / l0, sign * e0z / l0
        e1x, e1y, e1z = _cross(nrm[0], nrm[1], nrm[2], e0x, e0y, e0z)
        sign = -1.0 if e1y + e1z * gvz > 0 else 1.0  # counter-clockwise as displayed: image up is -y
        frames[k, 0, 0], frames[k, 0, 1], frames[k, 0, 2] = e0x, e0y, e0z
        frames[k, 1, 0], frames[k, 1, 1], frames[k, 1, 2] = sign * e1x, sign * e1y, sign * e1z
        centre[k] = p
        frames[k, 2] = nrm
        faces[k, 0], faces[k, 1], faces[k, 2] = x, y, t
    ring_step = radius / n_rings
    for job in prange(N * n_angles):
        k = job // n_angles
        a = job % n_angles
        if faces[k, 0] < 0:
            continue
        x, y, t = faces[k, 0], faces[k, 1], faces[k, 2]
        theta = 2.0 * np.pi * a / n_angles
        d = np.cos(theta) * frames[k, 0] + np.sin(theta) * frames[k, 1]
        nf = normals[y, x, t]
        u = _rotate_onto(d, frames[k, 2], nf)
        u -= (u * nf).sum() * nf
        u /= np.sqrt((u ** 2).sum())
        out = np.empty((n_rings, 3))
        reached[k, a] = _walk_one(points, face_ok, normals, x, y, t, centre[k], u, ring_step, n_rings, out, max_crossings)
        for r in range(n_rings):
            for c in range(3):
                samples[k, r, a, c] = out[r, c]
    return samples, reached, centre
