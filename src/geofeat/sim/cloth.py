"""A cloth of particles on a grid: Verlet integration plus distance constraints.

The cloth is a `rows x cols` grid of equal-mass particles (paper: 80 x 60), spacing `s` metres.
Particle (r, c) has the surface coordinate (u, v) = (c * s, r * s) metres on the flat rest cloth,
so on an isometric deformation the geodesic distance between two surface points equals the
Euclidean distance of their (u, v) coordinates (the rest cloth is a convex rectangle).

Constraints (distance constraints, solved by Gauss-Seidel projection as in the paper):
  * structural: (r, c)-(r, c+1) and (r, c)-(r+1, c). The paper's connectivity.
  * shear: the diagonal (r, c)-(r+1, c+1) of every cell, i.e. the third edge of the rendered
    triangles. Without it a cell can collapse into a rhombus, which keeps edge lengths but
    changes every other distance: the cloth would not stay isometric. Structural + this diagonal
    make every triangle rigid, with free hinges along the edges: exactly the isometric
    deformations of the triangle mesh.
  * soft constraints (a fraction `bending_stiffness` of the correction per sweep): the other
    diagonal (r, c+1)-(r+1, c) and bending pairs (r, c)-(r, c+2), (r, c)-(r+2, c). As hard
    constraints they would forbid folds along the diagonals and any curvature (a chord is shorter
    than its arc) and force strain into the structural edges; soft, they only resist creasing at
    the particle scale, which keeps the surface and its shading smooth.

Pinned particles also get long-range attachments ("tethers", a free particle is kept within its
rest (u, v) distance of every pin).

Solver ("small steps", Macklin et al. 2019): each time step of the paper is split into `substeps`
Verlet sub-steps of dt / substeps, each followed by one symmetric Gauss-Seidel pass (a forward sweep
over all constraints and a backward sweep over the hard ones). With the default 12 sub-steps that
is 24 sweeps per step, the paper's budget of 25, but the constraint error each sub-step has to
remove is substeps^2 times smaller. Over 12 random scenes x 30 frames (benchmarks/sim_strain.py)
the worst structural strain drops from 6.8 % (the paper's scheme: one step, then 24 sweeps) to
2.5 %, and the largest per-frame 99.9th percentile from 5.4 % to 1.2 %, at the same cost.

Why not exactly 0: a grid triangulation with inextensible edges has about as many constraints as
degrees of freedom (3 per vertex), so it "locks" (English & Bridson 2008): it can fold only along
its edges, and where a fold ends inside the cloth no isometric configuration exists. Even hundreds
of extra sweeps leave about 2 % on a few edges at such crease tips.

The sweeps run in parallel without changing their result with the thread count: the grid rows are
cut into blocks of at least 3 rows, a constraint belongs to the block of its upper particle, and
blocks of equal parity touch disjoint particles (a constraint reaches 2 rows down), so the even
blocks are swept in parallel, then the odd ones, each block serially in constraint order.

Time is dimensionless (paper: damping 0.01, dt^2 = 0.175); accelerations are in metres per
time unit squared, so `a * dt2` is a displacement in metres per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange


@dataclass(frozen=True)
class ClothConfig:
    """Cloth parameters.

    Attributes:
        rows, cols: grid size in particles (paper: 60 x 80).
        width_m: rest width (u extent) in metres; the height is width * (rows - 1) / (cols - 1).
        damping: Verlet velocity damping per step (paper: 0.01).
        dt2: squared time step (paper: 0.175).
        substeps: Verlet sub-steps per time step, each with a forward and a backward constraint
            sweep (2 * substeps sweeps per step; the paper has 25 sweeps after one full step).
        passes: symmetric (forward + backward) passes per sub-step; substeps=1, passes=12 is the
            paper's scheme (one Verlet step, then the sweeps), kept for comparison.
        shear, bending: add shear / bending constraints (see the module docstring).
        bending_stiffness: fraction of the correction of the soft constraints applied per sweep.
        solver_blocks: row blocks of the parallel sweep (at most rows // 3 are used).
    """

    rows: int = 60
    cols: int = 80
    width_m: float = 0.6
    damping: float = 0.01
    dt2: float = 0.175
    substeps: int = 12
    passes: int = 1
    shear: bool = True
    bending: bool = True
    bending_stiffness: float = 0.1
    solver_blocks: int = 8

    @property
    def spacing_m(self) -> float:
        """Rest distance between neighbouring particles, metres."""
        return self.width_m / (self.cols - 1)

    @property
    def height_m(self) -> float:
        """Rest height (v extent) in metres."""
        return self.spacing_m * (self.rows - 1)


def grid_constraints(rows: int, cols: int, spacing: float, shear: bool = True, bending: bool = True):
    """Distance constraints of a grid.

    Returns:
        pairs (C, 2) int32 particle indices (index = r * cols + c), rest (C,) float64 metres,
        kind (C,) int8: 0 structural, 1 shear along the triangulation diagonal (r, c)-(r+1, c+1),
        2 bending, 3 shear along the other diagonal (soft, see `Cloth.stiffness`).
    """
    idx = np.arange(rows * cols, dtype=np.int32).reshape(rows, cols)
    pairs, rest, kind = [], [], []

    def add(a: np.ndarray, b: np.ndarray, length: float, k: int) -> None:
        pairs.append(np.stack([a.ravel(), b.ravel()], axis=1))
        rest.append(np.full(a.size, length))
        kind.append(np.full(a.size, k, dtype=np.int8))

    add(idx[:, :-1], idx[:, 1:], spacing, 0)
    add(idx[:-1, :], idx[1:, :], spacing, 0)
    if shear:
        add(idx[:-1, :-1], idx[1:, 1:], spacing * np.sqrt(2.0), 1)
        add(idx[:-1, 1:], idx[1:, :-1], spacing * np.sqrt(2.0), 3)
    if bending:
        add(idx[:, :-2], idx[:, 2:], 2 * spacing, 2)
        add(idx[:-2, :], idx[2:, :], 2 * spacing, 2)
    return (
        np.ascontiguousarray(np.concatenate(pairs), dtype=np.int32),
        np.concatenate(rest),
        np.concatenate(kind),
    )


def grid_triangles(rows: int, cols: int) -> np.ndarray:
    """(T, 3) int32 triangles of the grid, T = 2 (rows - 1)(cols - 1).

    Cell (r, c) is split along the diagonal (r, c)-(r+1, c+1): triangle 2k holds
    (r, c), (r, c+1), (r+1, c+1) (the half with fu >= fv), triangle 2k+1 holds
    (r, c), (r+1, c+1), (r+1, c), where k = r * (cols - 1) + c and (fu, fv) the position in the cell.
    """
    idx = np.arange(rows * cols, dtype=np.int32).reshape(rows, cols)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    d, e = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    t0 = np.stack([a, b, e], axis=1)
    t1 = np.stack([a, e, d], axis=1)
    return np.ascontiguousarray(np.stack([t0, t1], axis=1).reshape(-1, 3))


def solver_blocks(pairs: np.ndarray, kind: np.ndarray, rows: int, cols: int, n_blocks: int):
    """Order the constraints for the block-parallel sweep (see the module docstring).

    Within a block the hard constraints (kind 0, 1) come first, then the soft ones, each in the
    order of `grid_constraints` (row by row: a forward sweep carries a correction down the whole
    block; a red-black order inside the block was tried and converged clearly slower).

    Returns:
        order (C,) int64: the constraints in sweep order,
        block_start (B + 1,) int64: block b holds order[block_start[b]:block_start[b + 1]],
        soft_start (B,) int64: where the soft constraints of block b start.
    """
    n_blocks = max(1, min(int(n_blocks), rows // 3))
    row_block = np.repeat(np.arange(n_blocks), [len(r) for r in np.array_split(np.arange(rows), n_blocks)])
    block = row_block[np.minimum(pairs[:, 0], pairs[:, 1]) // cols]
    soft = (kind >= 2).astype(np.int64)
    order = np.lexsort((np.arange(len(kind)), soft, block))
    block_start = np.searchsorted(block[order], np.arange(n_blocks + 1))
    soft_start = np.array([block_start[b] + np.count_nonzero((block == b) & (soft == 0)) for b in range(n_blocks)])
    return order, block_start.astype(np.int64), soft_start.astype(np.int64)


@njit(cache=True)
def _integrate(pos, prev, acc, pinned, pin_pos, damping, dt2):
    """One Verlet step in place; pinned particles are put at pin_pos (N, 3) with zero velocity."""
    n = pos.shape[0]
    keep = 1.0 - damping
    for i in range(n):
        if pinned[i]:
            for k in range(3):
                pos[i, k] = pin_pos[i, k]
                prev[i, k] = pin_pos[i, k]
        else:
            for k in range(3):
                p = pos[i, k]
                pos[i, k] = p + (p - prev[i, k]) * keep + acc[i, k] * dt2
                prev[i, k] = p


@njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _project(pos, j, k, rest, fj0, fk0):
    """Move particles j and k along their difference by fj0 / fk0 times the length error."""
    dx = pos[k, 0] - pos[j, 0]
    dy = pos[k, 1] - pos[j, 1]
    dz = pos[k, 2] - pos[j, 2]
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    if length < 1e-12:
        return
    f = 1.0 - rest / length
    fj = fj0 * f
    fk = fk0 * f
    pos[j, 0] += fj * dx
    pos[j, 1] += fj * dy
    pos[j, 2] += fj * dz
    pos[k, 0] -= fk * dx
    pos[k, 1] -= fk * dy
    pos[k, 2] -= fk * dz


@njit(cache=True, parallel=True, error_model="numpy", fastmath=True)
def _sweep(pos, pairs, rest, wj, wk, block_start, soft_start, phase, backward):
    """Gauss-Seidel sweep, in place, over the blocks of one parity `phase` (in parallel).

    Constraint c moves particle j towards k by wj[c] times the length error and k towards j by
    wk[c] (wj = wk = stiffness / 2 between free particles, 0 / stiffness next to a pinned one).
    A forward sweep visits a block's hard then soft constraints; a backward sweep only the hard
    ones, in reverse order.
    """
    n_blocks = block_start.shape[0] - 1
    for m in prange((n_blocks - phase + 1) // 2):
        b = phase + 2 * m
        if backward:
            for c in range(soft_start[b] - 1, block_start[b] - 1, -1):
                _project(pos, pairs[c, 0], pairs[c, 1], rest[c], wj[c], wk[c])
        else:
            for c in range(block_start[b], block_start[b + 1]):
                _project(pos, pairs[c, 0], pairs[c, 1], rest[c], wj[c], wk[c])


@njit(cache=True, parallel=True)
def _tethers(pos, pinned, pin_idx, uv):
    """Long-range attachments: a free particle may be no farther from a pinned particle than their
    rest (u, v) distance, which bounds the stretching that a few Gauss-Seidel sweeps leave."""
    n = pos.shape[0]
    for i in prange(n):
        if pinned[i]:
            continue
        for m in range(pin_idx.shape[0]):
            q = pin_idx[m]
            du = uv[i, 0] - uv[q, 0]
            dv = uv[i, 1] - uv[q, 1]
            rest = np.sqrt(du * du + dv * dv)
            dx = pos[i, 0] - pos[q, 0]
            dy = pos[i, 1] - pos[q, 1]
            dz = pos[i, 2] - pos[q, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d > rest and d > 1e-12:
                f = rest / d
                pos[i, 0] = pos[q, 0] + dx * f
                pos[i, 1] = pos[q, 1] + dy * f
                pos[i, 2] = pos[q, 2] + dz * f


@njit(cache=True)
def _substeps(pos, prev, acc, pinned, pin_from, pin_to, damping, dt2, substeps, passes,
              pairs, rest, wj, wk, block_start, soft_start, pin_idx, uv):
    """One time step as `substeps` Verlet sub-steps (dt / substeps, damping spread evenly, pins moved
    linearly from pin_from to pin_to), each followed by `passes` symmetric passes (a forward and a
    backward sweep); tethers are enforced before every other pass."""
    sub_dt2 = dt2 / (substeps * substeps)
    sub_damping = 1.0 - (1.0 - damping) ** (1.0 / substeps)
    pin_pos = pin_from.copy()
    for s in range(substeps):
        a = (s + 1) / substeps
        for i in pin_idx:
            for k in range(3):
                pin_pos[i, k] = pin_from[i, k] + (pin_to[i, k] - pin_from[i, k]) * a
        _integrate(pos, prev, acc, pinned, pin_pos, sub_damping, sub_dt2)
        for p in range(passes):
            count = s * passes + p
            if count % 2 == 0:
                _tethers(pos, pinned, pin_idx, uv)
            first = count % 2  # alternate which parity goes first, so that no block seam is always last
            _sweep(pos, pairs, rest, wj, wk, block_start, soft_start, first, False)
            _sweep(pos, pairs, rest, wj, wk, block_start, soft_start, 1 - first, False)
            _sweep(pos, pairs, rest, wj, wk, block_start, soft_start, 1 - first, True)
            _sweep(pos, pairs, rest, wj, wk, block_start, soft_start, first, True)


@njit(cache=True)
def vertex_normals(pos, rows, cols):
    """(N, 3) unit normals of a (rows * cols, 3) grid from central differences (one-sided at borders).

    Orientation: du x dv, which for the rest cloth facing a camera looking down +z points to +z
    (away from the camera).
    """
    out = np.empty((rows * cols, 3))
    for r in range(rows):
        r0 = max(r - 1, 0)
        r1 = min(r + 1, rows - 1)
        for c in range(cols):
            c0 = max(c - 1, 0)
            c1 = min(c + 1, cols - 1)
            i0 = r * cols + c0
            i1 = r * cols + c1
            j0 = r0 * cols + c
            j1 = r1 * cols + c
            ax = pos[i1, 0] - pos[i0, 0]
            ay = pos[i1, 1] - pos[i0, 1]
            az = pos[i1, 2] - pos[i0, 2]
            bx = pos[j1, 0] - pos[j0, 0]
            by = pos[j1, 1] - pos[j0, 1]
            bz = pos[j1, 2] - pos[j0, 2]
            nx = ay * bz - az * by
            ny = az * bx - ax * bz
            nz = ax * by - ay * bx
            norm = np.sqrt(nx * nx + ny * ny + nz * nz)
            if norm < 1e-15:
                norm = 1.0
            i = r * cols + c
            out[i, 0] = nx / norm
            out[i, 1] = ny / norm
            out[i, 2] = nz / norm
    return out


@njit(cache=True)
def _wind_forces(pos, normals, rows, cols, spacing, gravity, wind, wave_k, wave_phase, wave_amp):
    """acc (N, 3) = gravity + (n . w) n, w = wind * (1 + amp * sin(k . (u, v) + phase))."""
    n = rows * cols
    acc = np.empty((n, 3))
    for r in range(rows):
        for c in range(cols):
            i = r * cols + c
            u = c * spacing
            v = r * spacing
            s = 1.0 + wave_amp * np.sin(wave_k[0] * u + wave_k[1] * v + wave_phase)
            d = (normals[i, 0] * wind[0] + normals[i, 1] * wind[1] + normals[i, 2] * wind[2]) * s
            for k in range(3):
                acc[i, k] = gravity[k] + d * normals[i, k]
    return acc


class Cloth:
    """A cloth of `config.rows x config.cols` particles, initially flat.

    Attributes:
        config: the ClothConfig.
        pos: (N, 3) float64 particle positions, metres (N = rows * cols, index r * cols + c).
        prev: (N, 3) float64 positions one step earlier.
        pinned: (N,) bool particles held at `pin_pos` (change it with `pin`, which updates the solver).
        pin_pos: (N, 3) float64 target positions of pinned particles, metres.
        uv: (N, 2) float64 rest surface coordinates (u, v) = (c, r) * spacing, metres.
        pairs, rest, kind: the constraints (see `grid_constraints`), in sweep order (`solver_blocks`).
        triangles: (T, 3) int32 (see `grid_triangles`).
    """

    def __init__(self, config: ClothConfig = ClothConfig(), origin=(0.0, 0.0, 0.0), R: np.ndarray | None = None):
        """Lay the rest cloth out flat: particle (r, c) at origin + R @ (u, v, 0), metres."""
        if config.rows < 3 or config.cols < 3:
            raise ValueError(f"config: the grid needs at least 3 x 3 particles, got {config.rows} x {config.cols}")
        self.config = config
        rows, cols, s = config.rows, config.cols, config.spacing_m
        vv, uu = np.meshgrid(np.arange(rows) * s, np.arange(cols) * s, indexing="ij")
        self.uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
        flat = np.concatenate([self.uv, np.zeros((rows * cols, 1))], axis=1)
        R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64)
        self.pos = np.ascontiguousarray(flat @ R.T + np.asarray(origin, dtype=np.float64))
        self.prev = self.pos.copy()
        self.pinned = np.zeros(rows * cols, dtype=np.bool_)
        self.pin_pos = self.pos.copy()
        pairs, rest, kind = grid_constraints(rows, cols, s, config.shear, config.bending)
        order, self._block_start, self._soft_start = solver_blocks(pairs, kind, rows, cols, config.solver_blocks)
        self.pairs = np.ascontiguousarray(pairs[order])
        self.rest, self.kind = rest[order], kind[order]
        self.triangles = grid_triangles(rows, cols)
        #: (C,) fraction of each constraint's correction applied per sweep (bending is soft)
        self.stiffness = np.where(self.kind >= 2, config.bending_stiffness, 1.0)
        self._pin_last = self.pin_pos.copy()  # pin targets at the end of the last step
        self._weights: tuple[np.ndarray, np.ndarray] | None = None

    def pin(self, indices: np.ndarray, positions: np.ndarray | None = None) -> None:
        """Pin particles `indices` (M,) at `positions` (M, 3) metres (default: where they are)."""
        indices = np.asarray(indices, dtype=np.int64)
        self.pinned[indices] = True
        self.pin_pos[indices] = self.pos[indices] if positions is None else positions
        self._pin_last[indices] = self.pin_pos[indices]
        self._weights = None

    def _constraint_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(C,) wj, wk: the share of a constraint's correction that moves its first / second particle."""
        if self._weights is None:
            pj = self.pinned[self.pairs[:, 0]]
            pk = self.pinned[self.pairs[:, 1]]
            wj = np.where(pj, 0.0, np.where(pk, 1.0, 0.5)) * self.stiffness
            wk = np.where(pk, 0.0, np.where(pj, 1.0, 0.5)) * self.stiffness
            self._weights = (wj, wk)
        return self._weights

    def normals(self) -> np.ndarray:
        """(N, 3) unit vertex normals."""
        return vertex_normals(self.pos, self.config.rows, self.config.cols)

    def step(
        self,
        gravity: np.ndarray = np.zeros(3),
        wind: np.ndarray = np.zeros(3),
        wave_k: np.ndarray = np.zeros(2),
        wave_phase: float = 0.0,
        wave_amp: float = 0.0,
    ) -> None:
        """One time step: forces, then `config.substeps` Verlet sub-steps with constraint sweeps.
        Pinned particles move linearly from their targets at the last step to `pin_pos`.

        gravity, wind: (3,) accelerations in m / time unit^2. Wind acts along the normal with
        strength (n . wind), modulated over the cloth by 1 + wave_amp * sin(wave_k . (u, v) + phase)
        (wave_k in rad / m).
        """
        cfg = self.config
        acc = _wind_forces(
            self.pos, self.normals(), cfg.rows, cfg.cols, cfg.spacing_m,
            np.asarray(gravity, dtype=np.float64), np.asarray(wind, dtype=np.float64),
            np.asarray(wave_k, dtype=np.float64), float(wave_phase), float(wave_amp),
        )
        wj, wk = self._constraint_weights()
        _substeps(self.pos, self.prev, acc, self.pinned, self._pin_last, self.pin_pos, cfg.damping, cfg.dt2,
                  cfg.substeps, cfg.passes, self.pairs, self.rest, wj, wk, self._block_start, self._soft_start,
                  np.flatnonzero(self.pinned), self.uv)
        self._pin_last = self.pin_pos.copy()

    def strain(self, kind: int | None = 0) -> np.ndarray:
        """(C,) relative length error |d - rest| / rest of the constraints of one kind (None = all)."""
        sel = slice(None) if kind is None else self.kind == kind
        p = self.pairs[sel]
        d = np.linalg.norm(self.pos[p[:, 0]] - self.pos[p[:, 1]], axis=1)
        return np.abs(d - self.rest[sel]) / self.rest[sel]
