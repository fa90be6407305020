"""The thin-plate spline, one implementation for every caller.

A spline maps source pixels to destination pixels. Both sides are first normalised by a similarity
or scaling transform (`hartley_transform`, the default, or `size_transform`, the authors' division by
the image size (W, H)); in normalised coordinates the map is

    f(p) = [1, x, y] @ affine + sum_i weights[i] * U(|p - centres[i]|),  U(r) = r^2 log (r + eps)^2,

and destination pixels are the inverse destination transform applied to f(p). `eps` is 0 (the
classical kernel) except for the authors' files, whose kernel is r^2 log(r + 1e-6) (`AUTHORS_EPS`).

Users:
- ground truth (`geofeat.groundtruth`): the authors' `<k>_theta.npy` / `<k>_ctrlpts.npy` files
  (`ThinPlateSpline.from_authors_arrays`, `authors_tps` to fit one, `.authors_arrays()` to write it),
  and the landmark spline of sequences annotated with csv landmarks;
- tracking (`geofeat.apps.tracking`): RANSAC hypotheses fitted in one batch (`solve_batch`,
  `evaluate_batch`) and the regularised fit on the inliers.

The spline lives at the top of the package, not in `groundtruth/`, because it is a geometric tool
that the applications use for their own warps, not a source of ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .inputs import check_non_negative

__all__ = [
    "ThinPlateSpline", "fit_tps", "authors_tps", "hartley_transform", "size_transform", "normalise_points",
    "check_pairs", "check_regularisation", "kernel", "system_matrix", "solve_batch", "evaluate_batch", "AUTHORS_EPS",
    "MIN_POINTS", "spans_plane", "distinct_pairs",
]

#: Kernel offset of the authors' splines: U(r) = r^2 log (r + 1e-6)^2 (the files hold weights of r^2 log(r + 1e-6)).
AUTHORS_EPS = 1e-6
#: Fewest control points of a fit: 3 fix the affine part.
MIN_POINTS = 3
#: A set of control points "spans the plane" when the eigenvalues l1, l2 of its centred scatter
#: matrix have 4 l1 l2 / (l1 + l2)^2 above this (a shape measure: 1 for an isotropic set, 0 for collinear
#: or repeated points; for Hartley-normalised points it is about det / n^2).
_SPAN_TOL = 1e-6
#: Largest residual of a spline's linear system, relative to its right-hand side, that `fit_tps` accepts.
_SOLVE_TOL = 1e-6
#: Query points per block when evaluating (bounds the (block, C) kernel matrix).
_BLOCK = 4096

Normalisation = Literal["hartley", "size"]


def hartley_transform(xy: np.ndarray) -> np.ndarray:
    """(3, 3) similarity taking (N, 2) pixels to centroid 0 and mean distance sqrt(2) from it (Hartley)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    centre = xy.mean(axis=0)
    spread = np.linalg.norm(xy - centre, axis=1).mean()
    s = np.sqrt(2.0) / spread if spread > 1e-12 else 1.0
    return np.array([[s, 0, -s * centre[0]], [0, s, -s * centre[1]], [0, 0, 1.0]])


def size_transform(size: tuple[float, float]) -> np.ndarray:
    """(3, 3) scaling of pixels by 1 / (W, H), the authors' normalisation; size = (W, H) pixels."""
    values = np.asarray(size, np.float64).reshape(-1)
    if values.shape != (2,) or not (np.isfinite(values).all() and (values > 0).all()):
        raise ValueError(f"size: expected the image size (W, H) in pixels, got {size!r}")
    w, h = values
    return np.diag([1.0 / w, 1.0 / h, 1.0])


def _apply(T: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(3, 3) affine transform applied to (..., 2) points."""
    return xy @ T[:2, :2].T + T[:2, 2]


def normalise_points(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation of (N, 2) pixels: the (3, 3) transform T and the (N, 2) normalised points."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    T = hartley_transform(xy)
    return T, (xy - xy.mean(axis=0)) * T[0, 0]


def kernel(d2: np.ndarray, eps: float = 0.0) -> np.ndarray:
    """U = r^2 log (r + eps)^2 of squared distances d2 = r^2 (any shape, normalised units; U(0) = 0)."""
    if eps == 0.0:
        return np.where(d2 > 0, d2 * np.log(np.maximum(d2, 1e-300)), 0.0)
    return 2.0 * d2 * np.log(np.sqrt(np.maximum(d2, 0.0)) + eps)


def _sq_dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., N, 2), (..., M, 2) -> (..., N, M) squared distances."""
    return ((a[..., :, None, :] - b[..., None, :, :]) ** 2).sum(-1)


def system_matrix(src: np.ndarray, regularisation: float, eps: float) -> np.ndarray:
    """(B, n+3, n+3) spline system matrices [[K + regularisation * n * I, P], [P^T, 0]] of (B, n, 2) control points."""
    B, n, _ = src.shape
    P = np.concatenate([np.ones((B, n, 1)), src], axis=2)
    L = np.zeros((B, n + 3, n + 3))
    L[:, :n, :n] = kernel(_sq_dist(src, src), eps) + regularisation * n * np.eye(n)
    L[:, :n, n:] = P
    L[:, n:, :n] = P.transpose(0, 2, 1)
    return L


def spans_plane(xy: np.ndarray) -> bool:
    """Whether (N, 2) pixels span the plane (not all on one line, not all one point), by the rule
    `fit_tps` applies: a spline through them can be fitted only then."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return len(xy) >= 3 and bool(_spans_plane(normalise_points(xy)[1][None])[0])


def _spans_plane(src: np.ndarray) -> np.ndarray:
    """(B, n, 2) control points -> (B,) bool: not collinear (nor all repeated). A question of the
    points' shape, not of their size: a sample from a small cluster of points normalised with many
    others (RANSAC's, the refit on a compact set of inliers) spans the plane as well as the whole set."""
    centred = src - src.mean(axis=1, keepdims=True)
    scatter = np.einsum("bni,bnj->bij", centred, centred)
    trace = scatter[:, 0, 0] + scatter[:, 1, 1]
    return (trace > 0) & (4.0 * np.linalg.det(scatter) > _SPAN_TOL * trace**2)


def solve_batch(src: np.ndarray, dst: np.ndarray, regularisation: float = 0.0, eps: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit B splines at once, in normalised coordinates (vectorised: one batched linear solve).

    Args:
        src, dst: (B, n, 2) control points and their images, normalised coordinates.
        regularisation: smoothing; regularisation * n is added to the kernel diagonal (0 interpolates).
        eps: kernel offset (0, or `AUTHORS_EPS`).
    Returns:
        weights (B, n, 2), affine (B, 3, 2), ok (B,) bool (False for samples that do not span the
        plane, or whose system is singular: repeated control points without smoothing; their
        weights and affine part are meaningless).
    """
    n = src.shape[1]
    L = system_matrix(src, regularisation, eps)
    ok = _spans_plane(src)
    L[~ok] = np.eye(n + 3)
    rhs = np.zeros((len(src), n + 3, 2))
    rhs[:, :n] = dst
    try:
        sol = np.linalg.solve(L, rhs)
    except np.linalg.LinAlgError:  # a singular member (repeated control points, no smoothing) fails the batch
        sol = np.zeros_like(rhs)
        for b in range(len(L)):
            try:
                sol[b] = np.linalg.solve(L[b], rhs[b])
            except np.linalg.LinAlgError:
                ok[b] = False
    # an exactly singular member is not always noticed by LAPACK's LU, which then returns round-off
    # (weights of 1e28) instead of raising: a member whose solution does not solve its system fails
    residual = np.abs(np.einsum("bij,bjk->bik", L, sol) - rhs).max(axis=(1, 2))
    scale = 1.0 + np.abs(rhs).max(axis=(1, 2))
    ok &= np.isfinite(sol).all(axis=(1, 2)) & (residual <= _SOLVE_TOL * scale)
    return sol[:, :n], sol[:, n:], ok


def evaluate_batch(p: np.ndarray, centres: np.ndarray, weights: np.ndarray, affine: np.ndarray, eps: float = 0.0
                   ) -> np.ndarray:
    """B splines at the same (N, 2) normalised points: centres (B, n, 2), weights (B, n, 2),
    affine (B, 3, 2) -> (B, N, 2) normalised destination points."""
    out = np.einsum("ni,bij->bnj", np.concatenate([np.ones((len(p), 1)), p], axis=1), affine)
    return out + np.einsum("bns,bsj->bnj", kernel(_sq_dist(p[None], centres), eps), weights)


@dataclass(frozen=True)
class ThinPlateSpline:
    """A deformable-affine thin-plate spline from source pixels to destination pixels.

    Attributes:
        centres: (C, 2) control points, normalised source coordinates.
        weights: (C, 2) kernel weights.
        affine: (3, 2) affine part: [1, x, y] @ affine.
        src_transform, dst_transform: (3, 3) pixel -> normalised transforms of each side.
        eps: kernel offset, U(r) = r^2 log (r + eps)^2 (0, or `AUTHORS_EPS` for the authors' files).
    """

    centres: np.ndarray
    weights: np.ndarray
    affine: np.ndarray
    src_transform: np.ndarray
    dst_transform: np.ndarray
    eps: float = 0.0

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Map (M, 2) source pixels to (M, 2) destination pixels (any (..., 2) array is read as M points)."""
        xy = np.asarray(xy, np.float64)
        if xy.ndim == 0 or xy.shape[-1] != 2:  # reshaping an (M, 3) or (2, M) array would mix x and y
            raise ValueError(f"xy: expected (M, 2) pixels (x, y), got shape {xy.shape}")
        xy = xy.reshape(-1, 2)
        p = _apply(self.src_transform, xy)
        out = np.concatenate([np.ones((len(p), 1)), p], axis=1) @ self.affine
        c2 = (self.centres**2).sum(1)
        for s in range(0, len(p), _BLOCK):
            q = p[s : s + _BLOCK]
            d2 = np.maximum((q**2).sum(1)[:, None] + c2[None, :] - 2.0 * (q @ self.centres.T), 0.0)
            out[s : s + _BLOCK] += kernel(d2, self.eps) @ self.weights
        return _apply(np.linalg.inv(self.dst_transform), out)

    def authors_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(`theta` (1, C+3, 2) float32, `ctrlpts` (C, 2) float32) as the authors store them: weights of
        their kernel r^2 log(r + 1e-6) and the affine part of the displacement f(p) - p, in coordinates
        normalised by the image size. Only for splines made by `authors_tps`."""
        if self.eps != AUTHORS_EPS or not np.array_equal(self.src_transform, self.dst_transform):
            raise ValueError("authors_arrays: only a spline fitted by authors_tps has the authors' layout")
        displacement = self.affine - np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        theta = np.concatenate([2.0 * self.weights, displacement])
        return theta[None].astype(np.float32), self.centres.astype(np.float32)

    @classmethod
    def from_authors_arrays(cls, theta: np.ndarray, ctrlpts: np.ndarray, size: tuple[int, int]) -> ThinPlateSpline:
        """The authors' target -> reference spline (`<k>_theta.npy`, `<k>_ctrlpts.npy`).

        Args:
            theta: (1, T+3, 2) or (T+3, 2) = [w (T, 2); a (3, 2)], the displacement p -> f(p) - p with
                kernel r^2 log(r + 1e-6), in coordinates normalised by size.
            ctrlpts: (T, 2) control points, normalised coordinates.
            size: (W, H) of the images, pixels.
        """
        theta = np.asarray(theta, np.float64).reshape(-1, 2)
        ctrl = np.asarray(ctrlpts, np.float64).reshape(-1, 2)
        T = len(ctrl)
        if theta.shape[0] != T + 3:
            raise ValueError(f"theta: expected {T + 3} rows for {T} control points, got {theta.shape[0]}")
        affine = theta[T:] + np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        S = size_transform(size)
        return cls(ctrl, 0.5 * theta[:T], affine, S, S, AUTHORS_EPS)


def check_pairs(src, dst, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2), (N, 2) finite pixel pairs as float64, N >= minimum; ValueError otherwise."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if src.ndim != 2 or src.shape[1] != 2 or dst.shape != src.shape:
        raise ValueError(f"src, dst: expected two (N, 2) arrays of pixels, got shapes {src.shape} and {dst.shape}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("src, dst: pixel coordinates must be finite")
    if len(src) < minimum:
        raise ValueError(f"src, dst: a thin-plate spline needs >= {minimum} control points, got {len(src)}")
    return src, dst


def distinct_pairs(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The distinct (src, dst) pairs of (N, 2), (N, 2) pixel matches: (src (M, 2), dst (M, 2), copy_of),
    copy_of (N,) int64 the distinct pair of each match (so a verdict per distinct pair reads back as
    verdict[copy_of]), in the order of their first occurrence; src and dst themselves and copy_of None
    when no pair repeats. A repeated match (the same template and frame pixels, as SIFT's copies of
    one keypoint with another orientation give) is no more evidence than one, so the robust fits
    count it once."""
    _, first, inverse = np.unique(np.hstack([src, dst]), axis=0, return_index=True, return_inverse=True)
    if len(first) == len(src):
        return src, dst, None
    order = np.argsort(first)  # the distinct pairs in the order the matches first give them
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return src[first[order]], dst[first[order]], rank[inverse.reshape(-1)]


def check_regularisation(regularisation: float) -> float:
    """A spline's smoothing: a finite number >= 0 (0 interpolates); a negative one is not smoothing but
    a different, possibly singular, system. ValueError naming `regularisation` otherwise."""
    return check_non_negative(regularisation, "regularisation")


def fit_tps(src: np.ndarray, dst: np.ndarray, regularisation: float = 0.0, normalisation: Normalisation = "hartley",
            size: tuple[int, int] | None = None, eps: float = 0.0) -> ThinPlateSpline:
    """Fit a spline to all (N, 2) source -> (N, 2) destination pixel pairs (N >= 3, not collinear).

    Args:
        src, dst: (N, 2) control points and their images, pixels.
        regularisation: smoothing in normalised coordinates (regularisation * N on the kernel
            diagonal); 0 interpolates exactly.
        normalisation: "hartley" (each side: centroid 0, mean distance sqrt(2)) or "size" (both
            sides divided by size = (W, H), the authors').
        eps: kernel offset (0, or `AUTHORS_EPS`).
    Raises:
        ValueError: mismatched, non-finite or too few points; collinear points; a point repeated (or
            nearly) with different destinations, which no spline interpolates (repeated with the same
            destination is fine).
    """
    src, dst = check_pairs(src, dst, MIN_POINTS)
    check_regularisation(regularisation)
    if normalisation == "hartley":
        if size is not None:  # it was ignored: a caller meaning the authors' normalisation got Hartley's
            raise ValueError("size: only the 'size' normalisation uses the image size; give "
                             "normalisation='size' with it, or leave size out")
        Ts, Td = hartley_transform(src), hartley_transform(dst)
    elif normalisation == "size":
        if size is None:
            raise ValueError("size: the 'size' normalisation needs the image size (W, H)")
        Ts = Td = size_transform(size)
    else:
        raise ValueError(f"normalisation: expected 'hartley' or 'size', got {normalisation!r}")
    sn, dn = _apply(Ts, src), _apply(Td, dst)
    if not spans_plane(src):  # a question of shape, not of size: Hartley's frame
        raise ValueError("src: the points are collinear or repeated; a spline needs points spanning the plane")
    L = system_matrix(sn[None], regularisation, eps)[0]
    rhs = np.concatenate([dn, np.zeros((3, 2))])

    def solves(x: np.ndarray) -> bool:
        return bool(np.isfinite(x).all() and np.abs(L @ x - rhs).max() <= _SOLVE_TOL * (1.0 + np.abs(rhs).max()))

    try:
        sol = np.linalg.solve(L, rhs)
    except np.linalg.LinAlgError:  # repeated control points without smoothing
        sol = None
    if sol is None or not solves(sol):
        # an exactly repeated point makes L singular, but LAPACK's LU may not notice and return
        # round-off of 1e15 instead of raising: least squares solves it when the repeat has one destination
        sol = np.linalg.lstsq(L, rhs, rcond=None)[0]
    # the least-squares answer to a repeated point with two destinations, or the round-off of nearly
    # repeated ones, does not solve the system: a spline that misses its own control points
    if not solves(sol):
        raise ValueError("src: degenerate control points (repeated or nearly repeated points with different "
                         "destinations); the spline has no solution (smoothing, regularisation > 0, may have one)")
    n = len(sn)
    return ThinPlateSpline(sn, sol[:n], sol[n:], Ts, Td, eps)


def authors_tps(src: np.ndarray, dst: np.ndarray, size: tuple[int, int]) -> ThinPlateSpline:
    """Interpolating spline in the authors' parametrisation (coordinates divided by size = (W, H),
    kernel r^2 log(r + 1e-6)): `.authors_arrays()` gives their `theta` / `ctrlpts` files.
    src, dst: (N, 2) pixels, N >= 4 (the authors' minimum: 3 fix the affine part, one more bends it)."""
    if len(np.asarray(src).reshape(-1, 2)) < MIN_POINTS + 1:
        raise ValueError(f"src: a thin-plate spline needs >= {MIN_POINTS + 1} control points, got {len(src)}")
    return fit_tps(src, dst, normalisation="size", size=size, eps=AUTHORS_EPS)
