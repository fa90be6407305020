"""Heat-method geodesic distances on the grid mesh, and polar patches from their isocurves.

This is the slower reference path of the paper (its "Heatflow" row, after GeoBit, ICCV 2019):
geodesic distance from a keypoint by the heat method of Crane, Weischedel and Wardetzky (2013),

1. heat flow for a short time t: (M + t L) u = delta (one backward Euler step),
2. the normalised flow X = -grad u / |grad u| on every face,
3. the distance phi from the Poisson problem L phi = -div X, shifted so that it is 0 at the source
   (by default fitted a few pixels away from it, see `HeatGeodesics`),

with L the cotangent Laplacian (positive semi-definite) and M the lumped (barycentric) mass matrix
of the mesh's existing faces. Both matrices are factorised once per mesh with scipy's SuperLU
and reused for every source; the default t is the squared mean edge length. The heat step
averages the Neumann solution (natural boundary of L) and the Dirichlet one (u = 0 on the mesh
boundary) with weight `boundary_mix` (0.5, as GeoBit's libgeodesic setting and Crane et al.
recommend).

Polar patches: for every direction a straight line leaves the keypoint in the mesh image plane
(as GeoBit does); the distance map is read along it every `step_px` mesh pixels and each ring's
sample is placed where the distance first reaches (i + 1) * radius / n_rings, by linear
interpolation between the two samples around the crossing.
"""

from __future__ import annotations

import numbers
import warnings

import numpy as np
import scipy.sparse as sp
from numba import njit, prange
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from ..constants import DEFAULT_RADIUS_M, N_ANGLES, N_RINGS, SAMPLING_BLUR_PX
from ..depth import DepthConfig
from ..frame import RGBDFrame
from ..inputs import as_points, check_bool, check_in_range, check_positive
from .mesh import GridMesh, build_mesh, frame_fingerprint
from .polar import (PolarPatches, check_mesh_shape, check_patch_request, patch_source, patch_validity, sample_bilinear,
                    sampling_image)
from .walk import tangent_frames

#: Distance sampling step along an isocurve search line, mesh pixels (GeoBit: 0.05 full-res px).
HEAT_STEP_PX = 0.1
#: Keypoints whose distance maps are computed together (one multi-column sparse solve).
HEAT_BATCH = 16


def _locate(xy: np.ndarray, face_ok: np.ndarray) -> tuple[np.ndarray, ...]:
    """Faces containing (N, 2) mesh pixel coordinates, with the mesh's cell split.

    Returns x, y, t (N,) int64 cell and face indices, w (N, 3) barycentric weights and
    corners (N, 3, 2) int64 grid (column, row) of the face's vertices, and ok (N,) bool (the face
    exists). Vertex order: face 0 = (a, b, c), face 1 = (d, b, c), see `geofeat.geodesic.mesh`.
    """
    Hc, Wc = face_ok.shape[:2]
    x = np.floor(xy[:, 0]).astype(np.int64)
    y = np.floor(xy[:, 1]).astype(np.int64)
    inside = (x >= 0) & (y >= 0) & (x < Wc) & (y < Hc)
    fx, fy = xy[:, 0] - x, xy[:, 1] - y
    t = (fx + fy > 1.0).astype(np.int64)
    w = np.where(
        t[:, None] == 0,
        np.stack([1.0 - fx - fy, fx, fy], axis=1),
        np.stack([fx + fy - 1.0, 1.0 - fy, 1.0 - fx], axis=1),
    )
    first = np.stack([x + t, y + t], axis=1)
    corners = np.stack([first, np.stack([x + 1, y], 1), np.stack([x, y + 1], 1)], axis=1)
    xc, yc = np.clip(x, 0, Wc - 1), np.clip(y, 0, Hc - 1)
    ok = inside & face_ok[yc, xc, t]
    return x, y, t, w, corners, ok


def _check_sources(sources) -> np.ndarray:
    """`HeatGeodesics.distances_vertices`'s sources as (B, 2) float64 mesh pixel coordinates: (B, 2) or
    one (2,) point, finite; ValueError naming `sources` otherwise. (B, 3) points or a flat (2B,) list
    were reshaped into other sources without a word, and a NaN failed as an IndexError."""
    if np.shape(sources) == (2,):
        sources = [sources]
    xy = as_points(sources, "sources")
    if not np.isfinite(xy).all():
        bad = np.flatnonzero(~np.isfinite(xy).all(axis=1))
        raise ValueError(f"sources: NaN or infinite coordinates in rows {bad[:10].tolist()}")
    return xy


#: `HeatGeodesics` warns when it is given a heat time `t` above this multiple of its default (mean edge
#: length)^2: Crane et al. use the default; a diffusion length of ~30 edges is almost surely a unit mix-up.
HEAT_TIME_WARN_FACTOR = 1000.0
#: ... and below this multiple: heat that brief barely leaves the source's faces, and the distances come out short
#: (measured on a 160 x 120 plane 1 m away: by 7 % in the median at 0.1 times the default, 14 % at 0.01, against
#: 1 % at the default): on a mesh of a given edge length a smaller time is not more accurate.
HEAT_TIME_LOW_FACTOR = 0.1


class HeatGeodesics:
    """Heat-method geodesic distances on a `GridMesh`, factorised once for many sources.

    Args:
        mesh: the grid mesh (its existing faces form the triangle mesh).
        t: heat time, m^2; default (mean edge length)^2 (a warning below 0.1 or above 1000 times it).
        boundary_mix: weight of the Dirichlet heat solution against the Neumann one, in [0, 1]. A
            source on the boundary only (no heat on interior vertices) uses the Neumann solution
            alone, as the Dirichlet one vanishes there.
        calibrate: fix the additive constant of the distance so that it matches the straight-line
            distance to the source on the vertices 1.5 to 3.5 mesh pixels away (where geodesic and
            chord agree to within micrometres), instead of pinning it to 0 at the source. The
            heat method rounds the tip of the distance cone, which with pinning shortens every
            distance by about 0.4 edge lengths (1.7 mm on a plane at 1 m, 0.5 mesh scale);
            calibration removes that offset. False = the classic pinning (as potpourri3d).

    Attributes:
        V: (n, 3) float64 vertices, metres.
        F: (m, 3) int64 faces.
        index: (Hm, Wm) int64 grid vertex -> row of V (-1 unused).
        L: (n, n) cotangent Laplacian (positive semi-definite, csc).
        M: (n,) lumped vertex areas, m^2.
        t: heat time, m^2.
        component: (n,) connected component of every vertex.
        mean_edge: mean edge length, metres.
    """

    def __init__(
        self, mesh: GridMesh, t: float | None = None, boundary_mix: float = 0.5, calibrate: bool = True
    ) -> None:
        # a truthy calibrate="no" counted as True; boundary_mix="0.5" or None failed as a raw TypeError
        boundary_mix = check_in_range(boundary_mix, "boundary_mix", 0.0, 1.0)
        calibrate = check_bool(calibrate, "calibrate")
        if t is not None:  # t="1" was read as a number, t=True as 1 m^2
            t = check_positive(t, "t (heat time, m^2)")
        self.mesh = mesh
        V, F, index = mesh.vertices_faces()
        if len(F) == 0:
            raise ValueError("mesh: has no faces (no valid depth)")
        self.V, self.F, self.index = V, F, index
        n, m = len(V), len(F)
        P = V[F]  # (m, 3 corners, 3)
        cross = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        double_area = np.linalg.norm(cross, axis=1)
        self.area = 0.5 * double_area  # (m,) m^2
        normal = cross / double_area[:, None]
        # gradient operator: grad of the hat function of corner i = (n x e_i) / (2 A), e_i the
        # edge opposite corner i, oriented counter-clockwise about n
        rows, cols, vals = [], [], []
        for i in range(3):
            e = P[:, (i + 2) % 3] - P[:, (i + 1) % 3]
            g = np.cross(normal, e) / double_area[:, None]  # (m, 3)
            for c in range(3):
                rows.append(3 * np.arange(m) + c)
                cols.append(F[:, i])
                vals.append(g[:, c])
        self.G = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * m, n)
        )
        # cotangent Laplacian: L_jk = -(cot alpha + cot beta) / 2 over the angles opposite edge jk
        rows, cols, vals = [], [], []
        edge_len = []
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            u, v = P[:, j] - P[:, i], P[:, k] - P[:, i]
            w = 0.5 * np.einsum("ij,ij->i", u, v) / double_area  # cot of corner i / 2
            rows += [F[:, j], F[:, k], F[:, j], F[:, k]]
            cols += [F[:, k], F[:, j], F[:, j], F[:, k]]
            vals += [-w, -w, w, w]
            edge_len.append(np.linalg.norm(P[:, k] - P[:, j], axis=1))
        self.L = sp.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
        )
        self.M = np.bincount(F.ravel(), np.repeat(self.area / 3.0, 3), minlength=n)
        self.mean_edge = float(np.mean(np.concatenate(edge_len)))
        self.t = t if t is not None else self.mean_edge**2
        if not (np.isfinite(self.t) and self.t > 0):  # a mesh whose edges all have length 0
            raise ValueError(f"t: the default heat time (mean edge length)^2 is {self.t:g} m^2, not positive")
        if t is not None and self.t > HEAT_TIME_WARN_FACTOR * self.mean_edge**2:
            # potpourri3d's t_coef = 1.0 given as t = 1.0 m^2 is 10^5-10^6 times the default here
            warnings.warn(f"t: {self.t:g} m^2 is {self.t / self.mean_edge**2:.0f} times the default heat time, "
                          f"(mean edge length)^2 = {self.mean_edge**2:.3g} m^2; t is a time in m^2, not a multiple "
                          "of the default (potpourri3d's t_coef): heat this diffuse gives smooth, inaccurate distances",
                          stacklevel=2)
        if t is not None and self.t < HEAT_TIME_LOW_FACTOR * self.mean_edge**2:
            warnings.warn(f"t: {self.t:g} m^2 is {self.t / self.mean_edge**2:.2g} times the default heat time, "
                          f"(mean edge length)^2 = {self.mean_edge**2:.3g} m^2: heat this brief barely spreads past "
                          "the source's faces, and the distances come out short (by about 7 % at 0.1 times the "
                          "default, 14 % at 0.01, on a plane); a smaller t is not more accurate on this mesh",
                          stacklevel=2)
        self.boundary_mix = boundary_mix
        self.calibrate = calibrate
        # boundary vertices: ends of edges used by a single face
        edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        key = edges[:, 0] * n + edges[:, 1]
        uniq, counts = np.unique(key, return_counts=True)
        boundary = np.zeros(n, bool)
        boundary[uniq[counts == 1] // n] = True
        boundary[uniq[counts == 1] % n] = True
        self.boundary = boundary
        adjacency = sp.coo_matrix((np.ones(len(key)), (edges[:, 0], edges[:, 1])), shape=(n, n))
        self.n_components, self.component = connected_components(adjacency, directed=False)
        # factorisations, reused by every source
        A = (sp.diags(self.M) + self.t * self.L).tocsc()
        self._heat_matrix = A
        self._heat_neumann = splu(A, permc_spec="MMD_AT_PLUS_A") if boundary_mix < 1 else None
        self._interior = np.flatnonzero(~boundary)
        self._heat_dirichlet = None
        if boundary_mix > 0 and self._interior.size:
            Ai = A[self._interior][:, self._interior].tocsc()
            self._heat_dirichlet = splu(Ai, permc_spec="MMD_AT_PLUS_A")
        # L is singular (constants on every component): a tiny mass shift keeps it invertible
        # without visibly changing the zero-mean solutions the method asks for
        eps = 1e-8 / float(self.M.sum())
        self._poisson = splu((self.L + sp.diags(eps * self.M)).tocsc(), permc_spec="MMD_AT_PLUS_A")

    # ------------------------------------------------------------------ sources
    def _source_weights(self, sources: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(B, 2) mesh pixel sources -> (B, 3) rows of V, (B, 3) barycentric weights, (B,) ok."""
        _, _, _, w, corners, ok = _locate(sources, self.mesh.face_ok)
        Hm, Wm = self.index.shape
        cx = np.clip(corners[..., 0], 0, Wm - 1)
        cy = np.clip(corners[..., 1], 0, Hm - 1)
        rows = self.index[cy, cx]
        ok &= (rows >= 0).all(axis=1)
        return np.where(ok[:, None], rows, 0), w, ok

    def _as_sources(self, source) -> np.ndarray:
        """`distance`'s source -> (1, 2) float64 mesh pixel coordinates (x, y)."""
        Hm, Wm = self.index.shape
        if np.ndim(source) == 0:
            # a float (3.7) or a bool was truncated to a vertex index without a word
            if isinstance(source, (bool, np.bool_)) or not isinstance(source, numbers.Integral):
                raise ValueError(f"source: a grid vertex index must be an integer, got {source!r}; "
                                 "give sub-pixel sources as (x, y) mesh pixel coordinates")
            v = int(source)
            if not 0 <= v < Hm * Wm:
                raise ValueError(f"source: grid vertex {v} outside the {Wm}x{Hm} mesh")
            return np.array([[v % Wm, v // Wm]], dtype=np.float64)
        xy = np.asarray(source, dtype=np.float64)
        if xy.shape != (2,) or not np.isfinite(xy).all():
            raise ValueError(f"source: expected (x, y) mesh pixel coordinates or a grid vertex index, got {source!r}")
        return xy[None]

    # ------------------------------------------------------------------ solves
    def distances_vertices(self, sources: np.ndarray) -> np.ndarray:
        """Heat distances from B sources to every vertex of V.

        Args:
            sources: (B, 2) float64 mesh pixel coordinates (x, y), or one (2,) source; a source
                inside a face spreads its initial heat over the face's 3 vertices with barycentric
                weights. ValueError for another shape or a NaN or infinite coordinate.
        Returns:
            (n, B) float64 metres; NaN on components that do not hold the source, and for a source
            that lies on no face ((n, 0) for no source).
        """
        sources = _check_sources(sources)
        n, B = len(self.V), len(sources)
        if B == 0:  # no source: no column (the solves below cannot take none)
            return np.zeros((n, 0))
        rows, w, ok = self._source_weights(sources)
        delta = np.zeros((n, B))
        np.add.at(delta, (rows, np.broadcast_to(np.arange(B)[:, None], rows.shape)), w)
        # 1. heat flow; a source whose heat lies on boundary vertices only (a keypoint on the mesh's
        # border or a hole's, or a mesh without interior vertices) has no Dirichlet solution (u = 0
        # everywhere, so no flow and a distance of 0): it takes the Neumann one alone
        mix = np.full(B, self.boundary_mix)
        if self._heat_dirichlet is None:
            mix[:] = 0.0
        else:
            mix[delta[self._interior].sum(axis=0) <= 0] = 0.0
        u = np.zeros((n, B))
        if (mix < 1).any():
            if self._heat_neumann is None:  # boundary_mix = 1: factorised on first need
                self._heat_neumann = splu(self._heat_matrix, permc_spec="MMD_AT_PLUS_A")
            u += (1.0 - mix) * self._heat_neumann.solve(delta)
        if (mix > 0).any():
            u[self._interior] += mix * self._heat_dirichlet.solve(delta[self._interior])
        # 2. normalised flow per face
        grad = (self.G @ u).reshape(-1, 3, B)  # (m, 3, B)
        norm = np.linalg.norm(grad, axis=1, keepdims=True)
        X = -np.divide(grad, norm, out=np.zeros_like(grad), where=norm > 0)
        # 3. Poisson: L phi = -div X = G^T (A X)
        rhs = self.G.T @ (X * self.area[:, None, None]).reshape(-1, B)
        phi = self._poisson.solve(np.ascontiguousarray(rhs))
        phi -= self._offsets(sources, rows, w, ok, phi)[None, :]
        same = self.component[:, None] == self.component[rows[:, 0]][None, :]
        return np.where(same & ok[None, :], phi, np.nan)

    def _offsets(self, sources, rows, w, ok, phi) -> np.ndarray:
        """(B,) value of phi that means distance 0, per source (see `calibrate`)."""
        B = len(sources)
        at_source = (phi[rows, np.arange(B)[:, None]] * w).sum(axis=1)
        if not self.calibrate:
            return at_source
        # vertices 1.5 to 3.5 mesh pixels from the source, on its component
        Hm, Wm = self.index.shape
        oy, ox = np.mgrid[-4:5, -4:5]
        gx = np.floor(sources[:, 0])[:, None] + ox.ravel()[None, :]
        gy = np.floor(sources[:, 1])[:, None] + oy.ravel()[None, :]
        ring = np.hypot(gx - sources[:, :1], gy - sources[:, 1:])
        inside = (gx >= 0) & (gy >= 0) & (gx < Wm) & (gy < Hm) & (ring >= 1.5) & (ring <= 3.5)
        v = self.index[np.clip(gy, 0, Hm - 1).astype(int), np.clip(gx, 0, Wm - 1).astype(int)]
        use = inside & (v >= 0)
        v = np.where(use, v, 0)
        use &= self.component[v] == self.component[rows[:, :1]]
        p0 = (self.V[rows] * w[..., None]).sum(axis=1)  # (B, 3) source point
        chord = np.linalg.norm(self.V[v] - p0[:, None, :], axis=-1)
        gap = phi[v, np.arange(B)[:, None]] - chord
        count = use.sum(axis=1)
        mean_gap = np.where(use, gap, 0.0).sum(axis=1) / np.maximum(count, 1)
        return np.where(count > 0, mean_gap, at_source)

    def distance_maps(self, sources: np.ndarray) -> np.ndarray:
        """Heat distances from B sources as grid maps: (B, Hm, Wm) float64 metres, NaN off the mesh
        (and off the source's connected component). `sources`: (B, 2) mesh pixel coordinates (see
        `distances_vertices`)."""
        d = self.distances_vertices(sources)
        Hm, Wm = self.index.shape
        out = np.full((d.shape[1], Hm * Wm), np.nan)
        used = self.index.ravel() >= 0
        out[:, used] = d[self.index.ravel()[used]].T
        return out.reshape(-1, Hm, Wm)

    def distance(self, source) -> np.ndarray:
        """Heat geodesic distance from one source to every mesh vertex.

        Args:
            source: (x, y) mesh pixel coordinates (sub-pixel allowed; image pixels convert with
                `mesh.image_to_mesh`), or an int grid vertex index y * Wm + x.
        Returns:
            (Hm, Wm) float64 metres, NaN off the mesh; all NaN when the source lies on no face.
        """
        return self.distance_maps(self._as_sources(source))[0]


# ---------------------------------------------------------------------- isocurve marching
@njit(cache=True, inline="always")
def _value(grid, face_ok, x, y, out):
    """Linear interpolation of (Hm, Wm, C) vertex values at mesh pixel (x, y) in its mesh face;
    returns False (out untouched) when (x, y) lies on no face or a value is NaN."""
    Hc, Wc = face_ok.shape[0], face_ok.shape[1]
    cx = int(np.floor(x))
    cy = int(np.floor(y))
    if cx < 0 or cy < 0 or cx >= Wc or cy >= Hc:
        return False
    fx = x - cx
    fy = y - cy
    if fx + fy <= 1.0:
        if not face_ok[cy, cx, 0]:
            return False
        w0, w1, w2 = 1.0 - fx - fy, fx, fy
        x0, y0 = cx, cy
    else:
        if not face_ok[cy, cx, 1]:
            return False
        w0, w1, w2 = fx + fy - 1.0, 1.0 - fy, 1.0 - fx
        x0, y0 = cx + 1, cy + 1
    for c in range(out.shape[0]):
        v = w0 * grid[y0, x0, c] + w1 * grid[cy, cx + 1, c] + w2 * grid[cy + 1, cx, c]
        if not np.isfinite(v):
            return False
        out[c] = v
    return True


@njit(cache=True, parallel=True)
def march_isocurves(fields, face_ok, starts, dirs, ring_step, n_rings, step, max_steps):
    """Where straight image-plane lines meet the isocurves of per-source distance fields.

    Args:
        fields: (B, Hm, Wm, 4) float64 per source: heat distance (metres) and the vertex's 3D
            point (metres), NaN off the mesh.
        face_ok: (Hm - 1, Wm - 1, 2) bool, see `GridMesh`.
        starts: (B, 2) float64 mesh pixel coordinates of the sources.
        dirs: (B, A, 2) float64 unit line directions, mesh pixels.
        ring_step: distance between rings, metres; ring i lies at (i + 1) * ring_step.
        step: sampling step along a line, mesh pixels; max_steps: samples per line at most.
    Returns:
        xy (B, n_rings, A, 2) float64 mesh pixels, points (B, n_rings, A, 3) float64 metres and
        reached (B, A) int32 rings found before the line left the mesh. Rings beyond the end of a
        line repeat the last sample on the mesh; everything is NaN for a start on no face.
    """
    B, A = dirs.shape[0], dirs.shape[1]
    xy = np.full((B, n_rings, A, 2), np.nan)
    pts = np.full((B, n_rings, A, 3), np.nan)
    reached = np.zeros((B, A), dtype=np.int32)
    for job in prange(B * A):
        k = job // A
        a = job % A
        prev = np.empty(4)
        cur = np.empty(4)
        x0, y0 = starts[k, 0], starts[k, 1]
        if not _value(fields[k], face_ok, x0, y0, prev):
            continue
        dx, dy = dirs[k, a, 0], dirs[k, a, 1]
        px, py = x0, y0
        ring = 0
        for s in range(1, max_steps + 1):
            qx = x0 + s * step * dx
            qy = y0 + s * step * dy
            if not _value(fields[k], face_ok, qx, qy, cur):
                break
            while ring < n_rings and cur[0] >= (ring + 1) * ring_step:
                # crossing between prev and cur; the start itself can already lie beyond the
                # first ring (the heat distance is rounded near the source): the ring sits there
                rise = cur[0] - prev[0]
                f = ((ring + 1) * ring_step - prev[0]) / rise if rise > 0.0 else 0.0
                if f < 0.0:
                    f = 0.0
                xy[k, ring, a, 0] = px + f * (qx - px)
                xy[k, ring, a, 1] = py + f * (qy - py)
                for c in range(3):
                    pts[k, ring, a, c] = prev[1 + c] + f * (cur[1 + c] - prev[1 + c])
                ring += 1
            px, py = qx, qy
            for c in range(4):
                prev[c] = cur[c]
            if ring == n_rings:
                break
        reached[k, a] = ring
        for r in range(ring, n_rings):  # the line left the mesh: repeat its last point on it
            xy[k, r, a, 0] = px
            xy[k, r, a, 1] = py
            for c in range(3):
                pts[k, r, a, c] = prev[1 + c]
    return xy, pts, reached


def line_directions(mesh: GridMesh, starts: np.ndarray, n_angles: int, angles: str = "tangent") -> np.ndarray:
    """Unit mesh-image directions of the isocurve search lines: (N, n_angles, 2) float64.

    angles="image": column k leaves at image angle 2 pi k / n_angles, counter-clockwise as
    displayed (GeoBit). angles="tangent": the angle is measured in the surface's tangent plane
    at the keypoint from image +x projected onto it, as `geofeat.polar_patches` does, and the
    line follows the image of that tangent direction (on a slanted surface the two differ).
    Starts on no face get NaN. `starts`: (N, 2) mesh pixel coordinates.
    """
    theta = 2.0 * np.pi * np.arange(n_angles) / n_angles
    N = len(starts)
    if angles == "image":
        d = np.stack([np.cos(theta), -np.sin(theta)], axis=-1)
        return np.broadcast_to(d, (N, n_angles, 2)).copy()
    if angles != "tangent":
        raise ValueError(f"angles: expected 'tangent' or 'image', got {angles!r}")
    faces, p, frames = tangent_frames(mesh.points, mesh.face_ok, mesh.normals,
                                      np.ascontiguousarray(starts, dtype=np.float64))
    ok = faces[:, 0] >= 0
    e0, e1 = frames[:, 0], frames[:, 1]  # the walk's tangent frame: column 0 along image +x
    with np.errstate(invalid="ignore", divide="ignore"):
        X, Y, Z = p[:, 0], p[:, 1], p[:, 2]

        def image_of(e: np.ndarray) -> np.ndarray:  # Jacobian of the mesh projection at p
            K = mesh.K
            ex = e[:, 0] - X / Z * e[:, 2]
            ey = e[:, 1] - Y / Z * e[:, 2]
            return np.stack([(K[0, 0] * ex + K[0, 1] * ey) / Z, K[1, 1] * ey / Z], axis=1)

        j0, j1 = image_of(e0), image_of(e1)
        d = np.cos(theta)[None, :, None] * j0[:, None, :] + np.sin(theta)[None, :, None] * j1[:, None, :]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d[~ok] = np.nan
    return d


def heat_polar_patches(
    frame: RGBDFrame,
    keypoints,
    radius: float = DEFAULT_RADIUS_M,
    n_angles: int = N_ANGLES,
    n_rings: int = N_RINGS,
    depth_config: DepthConfig | str = "auto",
    mesh: GridMesh | None = None,
    blur_px: float = SAMPLING_BLUR_PX,
    solver: HeatGeodesics | None = None,
    angles: str = "tangent",
    step_px: float = HEAT_STEP_PX,
) -> PolarPatches:
    """Geodesic polar patches from heat-method isocurves (same layout as `geofeat.polar_patches`).

    Row i is the isocurve at heat distance (i + 1) * radius / n_rings; column k the straight
    mesh-image line at angle 2 pi k / n_angles (see `line_directions` for `angles`). A line that
    leaves the mesh (hole, border, discontinuity) before its outer ring repeats its last sample
    on the mesh in the remaining rings, which `rings_reached` counts out, as the walk does.

    Args:
        frame: the RGB-D frame.
        keypoints: (N, 2) image pixel coordinates (x, y) or a list of cv2.KeyPoint.
        radius: geodesic radius of the outer ring, metres.
        n_angles, n_rings: patch size (columns, rows).
        depth_config: depth preprocessing (ignored when `mesh` or `solver` is given).
        mesh: a prebuilt `build_mesh(frame, ...)`.
        blur_px: Gaussian blur of the gray image before sampling, full-resolution pixels.
        solver: a prebuilt `HeatGeodesics` of the mesh, to reuse its factorisation across calls
            (with `mesh` too, it must be `solver.mesh`).
        angles: "tangent" (default, the walk's convention) or "image" (GeoBit's image angles).
        step_px: sampling step along a line, mesh pixels.
    """
    kp = check_patch_request(frame, keypoints, radius, n_angles, n_rings)
    step_px = check_positive(step_px, "step_px")  # "1" failed in np.isfinite with a bare TypeError
    if solver is not None:
        if mesh is not None and mesh is not solver.mesh:  # the solver's mesh was used, `mesh` ignored
            raise ValueError("mesh: differs from solver.mesh; give one of them, or a solver built on this mesh")
        mesh = solver.mesh
    elif mesh is None:
        mesh = build_mesh(frame, depth_config)
    source = frame_fingerprint(frame)
    check_mesh_shape(mesh, frame, source)
    N = len(kp)
    xy = np.full((N, n_rings, n_angles, 2), np.nan)
    pts = np.full((N, n_rings, n_angles, 3), np.nan)
    reached = np.zeros((N, n_angles), np.int32)
    starts = mesh.image_to_mesh(kp) if N else np.zeros((0, 2))
    on = _locate(starts, mesh.face_ok)[-1] if N else np.zeros(0, bool)
    if on.any():
        if solver is None:
            solver = HeatGeodesics(mesh)
        dirs = line_directions(mesh, starts, n_angles, angles)
        Hm, Wm = mesh.points.shape[:2]
        max_steps = int(np.ceil(np.hypot(Hm, Wm) / step_px)) + 1
        todo = np.flatnonzero(on)
        for b in range(0, len(todo), HEAT_BATCH):
            idx = todo[b : b + HEAT_BATCH]
            dist = solver.distance_maps(starts[idx])
            fields = np.concatenate([dist[..., None], np.broadcast_to(mesh.points, dist.shape + (3,))], axis=-1)
            xy[idx], pts[idx], reached[idx] = march_isocurves(
                fields, mesh.face_ok, starts[idx], dirs[idx], float(radius) / n_rings, int(n_rings),
                float(step_px), max_steps,
            )
    valid = on & patch_validity(reached)
    sx, sy = mesh.scale
    coords = np.stack([(xy[..., 0] + 0.5) / sx - 0.5, (xy[..., 1] + 0.5) / sy - 0.5], axis=-1).astype(np.float32)
    coords[~valid] = np.nan
    values = sample_bilinear(sampling_image(frame, blur_px), np.nan_to_num(coords, nan=-1.0))
    values[~valid] = 0.0
    return PolarPatches(
        keypoints=kp,
        values=values.astype(np.float32),
        coords=coords,
        valid=valid,
        rings_reached=reached,
        points=pts.astype(np.float32),
        radius=float(radius),
        source=patch_source(frame, source),
        blur_px=float(blur_px),
        depth_config=getattr(mesh, "config", None),
    )
