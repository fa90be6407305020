"""Thin-plate splines: the authors' layout (`TPS`, `authors_tps_warp`), the robust landmark spline
(`robust_landmark_tps`) and the benchmark's landmark spline (`LandmarkTPS`, scipy).

The authors' target -> reference warp (`authors_tps_warp`) works in
coordinates normalised by the image size (W, H): `warped = p + [1, x, y] a + U(p) w` with
`U = d^2 log(d + 1e-6)` over the distances d from p to the control points. `TPS` fits exactly that
form, so its `theta` / `ctrlpts` can be written as `<k>_theta.npy` / `<k>_ctrlpts.npy` unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay

#: Fewest landmarks a spline with an affine part needs (3 fix the affine part; one more bends it).
MIN_LANDMARKS = 4
#: A landmark is rejected when its leave-one-out residual exceeds this many pixels and
#: `OUTLIER_FACTOR` times the median leave-one-out residual of the others.
OUTLIER_MIN_PX = 8.0
OUTLIER_FACTOR = 4.0


def _kernel(d: np.ndarray) -> np.ndarray:
    return d**2 * np.log(d + 1e-6)


class TPS:
    """Thin-plate spline mapping pixels of one image to another, in the authors' parametrisation.

    Args:
        src: (T, 2) control points, pixels of the source image.
        dst: (T, 2) their images, pixels of the destination image.
        size: (W, H) of the images, pixels (the spline works in coordinates normalised by it).
        regularization: added to the kernel diagonal (normalised units); 0 interpolates exactly.
    """

    def __init__(self, src: np.ndarray, dst: np.ndarray, size: tuple[int, int], regularization: float = 0.0) -> None:
        src = np.asarray(src, float).reshape(-1, 2)
        dst = np.asarray(dst, float).reshape(-1, 2)
        if len(src) != len(dst):
            raise ValueError(f"dst: expected {len(src)} points like src, got {len(dst)}")
        if len(src) < MIN_LANDMARKS:
            raise ValueError(f"src: a thin-plate spline needs >= {MIN_LANDMARKS} control points, got {len(src)}")
        self.size = np.asarray(size, float)
        c = src / self.size
        v = dst / self.size - c
        T = len(c)
        L = np.zeros((T + 3, T + 3))
        L[:T, :T] = _kernel(np.linalg.norm(c[:, None] - c[None], axis=-1)) + regularization * np.eye(T)
        P = np.concatenate([np.ones((T, 1)), c], axis=1)
        L[:T, T:] = P
        L[T:, :T] = P.T
        rhs = np.concatenate([v, np.zeros((3, 2))])
        try:
            theta = np.linalg.solve(L, rhs)
        except np.linalg.LinAlgError:
            theta = np.linalg.lstsq(L, rhs, rcond=None)[0]
        if not np.isfinite(theta).all():
            raise ValueError("src: degenerate control points (collinear or repeated); the spline has no solution")
        self.ctrlpts = c
        self.theta = theta

    def __call__(self, xy: np.ndarray, chunk: int = 8192) -> np.ndarray:
        """(N, 2) source pixels -> (N, 2) destination pixels."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        out = np.empty_like(xy)
        T = len(self.ctrlpts)
        w, a = self.theta[:T], self.theta[T:]
        for i in range(0, len(xy), chunk):
            p = xy[i:i + chunk] / self.size
            U = _kernel(np.linalg.norm(p[:, None] - self.ctrlpts[None], axis=-1))
            out[i:i + chunk] = (p + a[0] + p @ a[1:] + U @ w) * self.size
        return out

    def authors_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(`theta` (1, T+3, 2) float32, `ctrlpts` (T, 2) float32) as the authors store them."""
        return self.theta[None].astype(np.float32), self.ctrlpts.astype(np.float32)


@dataclass
class RobustFit:
    """A landmark spline with its inliers.

    Attributes:
        tps: the spline fitted to the inliers.
        inliers: (N,) bool over the landmarks given to `robust_landmark_tps`.
        loo_px: (N,) leave-one-out residual of each landmark in pixels (NaN for rejected ones): how far
            the spline fitted to the other inliers predicts it.
    """

    tps: TPS
    inliers: np.ndarray
    loo_px: np.ndarray


def _loo_residuals(src: np.ndarray, dst: np.ndarray, size) -> np.ndarray:
    """Leave-one-out residual (pixels) of each landmark under an interpolating spline.

    For an interpolating spline the prediction of point i from the others follows from the inverse
    of the system matrix: residual_i = c_i / (L^-1)_ii with c = L^-1 rhs (the kernel weights)."""
    size = np.asarray(size, float)
    c = src / size
    T = len(c)
    L = np.zeros((T + 3, T + 3))
    L[:T, :T] = _kernel(np.linalg.norm(c[:, None] - c[None], axis=-1))
    P = np.concatenate([np.ones((T, 1)), c], axis=1)
    L[:T, T:], L[T:, :T] = P, P.T
    Linv = np.linalg.pinv(L)
    rhs = np.concatenate([dst / size - c, np.zeros((3, 2))])
    w = (Linv @ rhs)[:T]
    diag = np.diag(Linv)[:T]
    return np.linalg.norm(w / np.where(np.abs(diag) > 1e-12, diag, np.nan)[:, None] * size, axis=1)


def robust_landmark_tps(src: np.ndarray, dst: np.ndarray, size: tuple[int, int]) -> RobustFit:
    """Deformable-affine thin-plate spline src -> dst through landmarks, robust to a few mislabelled ones.

    The landmark with the largest leave-one-out residual is dropped while that residual exceeds both
    `OUTLIER_MIN_PX` and `OUTLIER_FACTOR` times the median of the others (at most a third of the
    landmarks are dropped); the spline then interpolates the remaining ones.

    Args:
        src, dst: (N, 2) landmark pixels in the source and destination images (same order).
        size: (W, H) image size, pixels.
    """
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    n = len(src)
    if n < MIN_LANDMARKS:
        raise ValueError(f"landmarks: a thin-plate spline needs >= {MIN_LANDMARKS} landmarks visible in both frames, got {n}")
    inliers = np.ones(n, bool)
    loo = np.full(n, np.nan)
    while True:
        idx = np.flatnonzero(inliers)
        r = _loo_residuals(src[idx], dst[idx], size) if len(idx) > MIN_LANDMARKS else np.zeros(len(idx))
        loo[:] = np.nan
        loo[idx] = r
        if len(idx) <= max(MIN_LANDMARKS + 2, int(np.ceil(2 * n / 3))) or not np.isfinite(r).all():
            break
        worst = int(np.argmax(r))
        others = np.delete(r, worst)
        if r[worst] <= max(OUTLIER_MIN_PX, OUTLIER_FACTOR * float(np.median(others))):
            break
        inliers[idx[worst]] = False
    return RobustFit(TPS(src[inliers], dst[inliers], size), inliers, loo)


class LandmarkTPS:
    """Thin-plate spline from target to reference pixels fitted to landmarks visible in both frames
    (scipy RBFInterpolator). Points outside the convex hull of the target landmarks map to NaN."""

    def __init__(self, tgt_xy: np.ndarray, ref_xy: np.ndarray, smoothing: float = 0.0) -> None:
        tgt_xy, ref_xy = np.asarray(tgt_xy, float), np.asarray(ref_xy, float)
        if len(tgt_xy) < 4:
            raise ValueError(f"landmarks: a thin-plate spline needs >= 4 landmarks visible in both frames, got {len(tgt_xy)}")
        self._rbf = RBFInterpolator(tgt_xy, ref_xy, kernel="thin_plate_spline", smoothing=smoothing)
        self._hull = Delaunay(tgt_xy)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        if len(xy) == 0:
            return np.zeros((0, 2))
        out = self._rbf(xy)
        out[self._hull.find_simplex(xy) < 0] = np.nan
        return out


def authors_tps_warp(xy: np.ndarray, theta: np.ndarray, ctrlpts: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The authors' published target->reference warp (`<k>_theta.npy`, `<k>_ctrlpts.npy`).

    Args:
        xy: (N, 2) target pixels. theta: (1, T+3, 2) or (T+3, 2) = [w (T, 2); a (3, 2)].
        ctrlpts: (T, 2) control points. size: (W, H) of the images (the TPS works in coordinates
            normalised by (W, H)).
    Returns:
        (N, 2) reference pixels: warped = p + [1, x, y] a + U w, U = d^2 log(d + 1e-6).
    """
    theta = np.asarray(theta, float).reshape(-1, 2)
    ctrl = np.asarray(ctrlpts, float).reshape(-1, 2)
    T = ctrl.shape[0]
    if theta.shape[0] != T + 3:
        raise ValueError(f"theta: expected {T + 3} rows for {T} control points, got {theta.shape[0]}")
    w, a = theta[:T], theta[T:]
    wh = np.asarray(size, float)
    p = np.asarray(xy, float).reshape(-1, 2) / wh
    d = np.linalg.norm(p[:, None, :] - ctrl[None, :, :], axis=-1)
    U = d**2 * np.log(d + 1e-6)
    affine = np.concatenate([np.ones((len(p), 1)), p], axis=1) @ a
    return (p + affine + U @ w) * wh
