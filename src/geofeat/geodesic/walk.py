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


@njit(cache=True, inline="always")
def _corner(x, y, t, i):
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


@njit(cache=True, inline="always")
def _edge_ends(x, y, t, e):
    """Grid positions (x0, y0, x1, y1) of the two ends of local edge e of face (x, y, t)."""
    i0 = 1 if e == 0 else 0
    i1 = 1 if e == 2 else 2
    x0, y0 = _corner(x, y, t, i0)
    x1, y1 = _corner(x, y, t, i1)
    return x0, y0, x1, y1


@njit(cache=True)
def _edge_hit(points, x, y, t, e, px, py, pz, ux, uy, uz, nx, ny, nz):
    """Intersection of the ray p + d u with local edge e of face (x, y, t), in the face plane.

    Returns (d, s): the distance along the ray and the edge parameter (0 at the first end, 1 at the
    second). d is -1 when the ray is parallel to the edge."""
    x0, y0, x1, y1 = _edge_ends(x, y, t, e)
    ax, ay, az = points[y0, x0, 0], points[y0, x0, 1], points[y0, x0, 2]
    ex, ey, ez = points[y1, x1, 0] - ax, points[y1, x1, 1] - ay, points[y1, x1, 2] - az
    c0, c1, c2 = _cross(ux, uy, uz, ex, ey, ez)
    denom = c0 * nx + c1 * ny + c2 * nz
    if abs(denom) < 1e-18:
        return -1.0, 0.0
    wx, wy, wz = ax - px, ay - py, az - pz
    a0, a1, a2 = _cross(wx, wy, wz, ex, ey, ez)
    b0, b1, b2 = _cross(wx, wy, wz, ux, uy, uz)
    return (a0 * nx + a1 * ny + a2 * nz) / denom, (b0 * nx + b1 * ny + b2 * nz) / denom


@njit(cache=True, inline="always")
def _side(points, x, y, t, i, px, py, pz, ux, uy, uz, nx, ny, nz):
    """Signed side of local vertex i relative to the ray (positive = left of u about n)."""
    vx, vy = _corner(x, y, t, i)
    c0, c1, c2 = _cross(ux, uy, uz, points[vy, vx, 0] - px, points[vy, vx, 1] - py, points[vy, vx, 2] - pz)
    return c0 * nx + c1 * ny + c2 * nz


@njit(cache=True)
def _walk_one(points, face_ok, normals, x, y, t, p0, u0, ring_step, n_rings, out, max_crossings):
    """Walk one ray from point p0 (on face (x, y, t)) in direction u0 (unit, in that face's plane).

    Writes the 3D points at arc lengths (i + 1) * ring_step, i < n_rings, into out (n_rings, 3);
    rings beyond the end of the mesh repeat the last point reached. Returns the number of rings
    reached on the mesh. Scalar arithmetic only: no allocation inside the loop."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    px, py, pz = p0[0], p0[1], p0[2]
    ux, uy, uz = u0[0], u0[1], u0[2]
    nx, ny, nz = normals[y, x, t, 0], normals[y, x, t, 1], normals[y, x, t, 2]
    length = 0.0
    ring = 0
    entry = -1
    for _ in range(max_crossings):
        # choose the exit edge
        if entry < 0:
            exit_edge = -1
            d = np.inf
            s = 0.0
            for e in range(3):
                de, se = _edge_hit(points, x, y, t, e, px, py, pz, ux, uy, uz, nx, ny, nz)
                if de > 1e-15 and -1e-9 <= se <= 1.0 + 1e-9 and de < d:
                    exit_edge, d, s = e, de, se
            if exit_edge < 0:
                break
        else:
            # the exit is one of the two edges through the vertex opposite the entry edge
            i1 = 1 if entry == 0 else 0
            i2 = 1 if entry == 2 else 2
            side_r = _side(points, x, y, t, entry, px, py, pz, ux, uy, uz, nx, ny, nz)
            side_1 = _side(points, x, y, t, i1, px, py, pz, ux, uy, uz, nx, ny, nz)
            exit_edge = i2 if side_r * side_1 <= 0.0 else i1
            d, s = _edge_hit(points, x, y, t, exit_edge, px, py, pz, ux, uy, uz, nx, ny, nz)
            if d < 0.0:
                d = 0.0
        # emit the rings that lie on this segment
        while ring < n_rings and length + d >= (ring + 1) * ring_step:
            r = (ring + 1) * ring_step - length
            out[ring, 0] = px + r * ux
            out[ring, 1] = py + r * uy
            out[ring, 2] = pz + r * uz
            ring += 1
        if ring == n_rings:
            return ring
        # move to the edge point (clamped onto the edge for robustness)
        s = min(max(s, 0.0), 1.0)
        x0, y0, x1, y1 = _edge_ends(x, y, t, exit_edge)
        ax, ay, az = points[y0, x0, 0], points[y0, x0, 1], points[y0, x0, 2]
        ex, ey, ez = points[y1, x1, 0] - ax, points[y1, x1, 1] - ay, points[y1, x1, 2] - az
        qx, qy, qz = ax + s * ex, ay + s * ey, az + s * ez
        length += np.sqrt((qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2)
        px, py, pz = qx, qy, qz
        # cross into the neighbouring face
        xn, yn, tn, entry_n = _neighbour(x, y, t, exit_edge)
        if xn < 0 or yn < 0 or xn >= Wc or yn >= Hc or not face_ok[yn, xn, tn]:
            break
        # unfold: keep the component along the edge, carry the across-edge component into the
        # new face plane (rotation about the edge taking n to n2)
        el = np.sqrt(ex * ex + ey * ey + ez * ez)
        ex, ey, ez = ex / el, ey / el, ez / el
        mx, my, mz = normals[yn, xn, tn, 0], normals[yn, xn, tn, 1], normals[yn, xn, tn, 2]
        m1x, m1y, m1z = _cross(ex, ey, ez, nx, ny, nz)
        m2x, m2y, m2z = _cross(ex, ey, ez, mx, my, mz)
        along = ux * ex + uy * ey + uz * ez
        across = ux * m1x + uy * m1y + uz * m1z
        ux = along * ex + across * m2x
        uy = along * ey + across * m2y
        uz = along * ez + across * m2z
        ul = np.sqrt(ux * ux + uy * uy + uz * uz)
        ux, uy, uz = ux / ul, uy / ul, uz / ul
        nx, ny, nz = mx, my, mz
        x, y, t, entry = xn, yn, tn, entry_n
    # the ray left the mesh: later rings repeat the last point reached
    for r in range(ring, n_rings):
        out[r, 0] = px
        out[r, 1] = py
        out[r, 2] = pz
    return ring


@njit(cache=True, inline="always")
def _rotate_onto(vx, vy, vz, ax, ay, az, bx, by, bz):
    """Rotate v by the smallest rotation that takes unit a to unit b (Rodrigues)."""
    kx, ky, kz = _cross(ax, ay, az, bx, by, bz)
    sin_a = np.sqrt(kx * kx + ky * ky + kz * kz)
    cos_a = ax * bx + ay * by + az * bz
    if sin_a < 1e-12:
        return vx, vy, vz
    kx, ky, kz = kx / sin_a, ky / sin_a, kz / sin_a
    cx, cy, cz = _cross(kx, ky, kz, vx, vy, vz)
    kv = (kx * vx + ky * vy + kz * vz) * (1 - cos_a)
    return vx * cos_a + cx * sin_a + kx * kv, vy * cos_a + cy * sin_a + ky * kv, vz * cos_a + cz * sin_a + kz * kv


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
def walk_polar(points, face_ok, normals, starts, K, radius, n_angles, n_rings, max_crossings):
    """Geodesic polar samples around many start points.

    Args:
        points: (Hm, Wm, 3) float64 mesh vertices, metres.
        face_ok, normals: see `GridMesh`.
        starts: (N, 2) float64 mesh pixel coordinates of the keypoints.
        K: (3, 3) intrinsics of the image that samples are projected into.
        radius: geodesic radius of the outer ring, metres.
    Returns:
        samples (N, n_rings, n_angles, 3) float32 metres, coords (N, n_rings, n_angles, 2) float32
        image pixels (x, y) of the samples projected with K, reached (N, n_angles) int32 rings
        reached per direction, centre (N, 3) float64 start point (NaN when the start has no face).
    """
    N = starts.shape[0]
    samples = np.full((N, n_rings, n_angles, 3), np.nan, dtype=np.float32)
    coords = np.full((N, n_rings, n_angles, 2), np.nan, dtype=np.float32)
    reached = np.zeros((N, n_angles), dtype=np.int32)
    centre = np.full((N, 3), np.nan)
    frames = np.zeros((N, 3, 3))  # per keypoint: e0, e1, normal of the start face
    faces = np.full((N, 3), -1, dtype=np.int64)
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    for k in prange(N):
        x, y, t, w0, w1, w2 = _locate(face_ok, starts[k, 0], starts[k, 1])
        if x < 0 or not face_ok[y, x, t]:
            continue
        xa, ya = _corner(x, y, t, 0)
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
        c, sn = np.cos(theta), np.sin(theta)
        dx = c * frames[k, 0, 0] + sn * frames[k, 1, 0]
        dy = c * frames[k, 0, 1] + sn * frames[k, 1, 1]
        dz = c * frames[k, 0, 2] + sn * frames[k, 1, 2]
        fnx, fny, fnz = normals[y, x, t, 0], normals[y, x, t, 1], normals[y, x, t, 2]
        ux, uy, uz = _rotate_onto(dx, dy, dz, frames[k, 2, 0], frames[k, 2, 1], frames[k, 2, 2], fnx, fny, fnz)
        un = ux * fnx + uy * fny + uz * fnz
        ux, uy, uz = ux - un * fnx, uy - un * fny, uz - un * fnz
        ul = np.sqrt(ux * ux + uy * uy + uz * uz)
        u = np.empty(3)
        u[0], u[1], u[2] = ux / ul, uy / ul, uz / ul
        out = samples[k, :, a, :]
        reached[k, a] = _walk_one(points, face_ok, normals, x, y, t, centre[k], u, ring_step, n_rings, out, max_crossings)
        for r in range(n_rings):
            X, Y, Z = float(out[r, 0]), float(out[r, 1]), float(out[r, 2])
            coords[k, r, a, 0] = K[0, 0] * X / Z + K[0, 1] * Y / Z + K[0, 2]
            coords[k, r, a, 1] = K[1, 1] * Y / Z + K[1, 2]
    return samples, coords, reached, centre
