"""Photometric refinement of a reference -> frame deformation on a regular control-point grid.

Model: `f(p) = f0(p) + D(p)`, with f0 the landmark spline (reference -> frame pixels) and D a
displacement field interpolated with cubic B-splines from coefficients on a regular grid of control
points over the object in the reference frame, spacing `spacing` pixels. D is optimised with L-BFGS
(`torch.optim.LBFGS`) coarse to fine over a Gaussian pyramid, minimising

    mean over object pixels of (1 - local NCC(reference, frame warped into the reference))
    + bending * mean |second differences of D|^2 / spacing^2
    + landmarks * mean log(1 + |f(l_ref) - l_frame|^2 / sigma^2)     (Cauchy, soft constraints)

Local NCC (window `window` pixels at every level) ignores the smooth shading changes of a moving
cloth; it is bounded, so an occluded window costs at most a constant and pulls nothing. Pixels whose
warped position leaves the frame are masked out, as are flat windows (weight var / (var + tau)).
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..inputs import check_non_negative, check_positive, check_whole
from .defaults import DEFAULT_SPACING_PX

#: A map of (N, 2) pixels to (N, 2) pixels, e.g. a `geofeat.tps.ThinPlateSpline`.
Warp = Callable[[np.ndarray], np.ndarray]


@dataclass
class RefineConfig:
    """Refinement settings. spacing, sigma_px in pixels; bending, landmarks are weights."""

    spacing: float = DEFAULT_SPACING_PX
    levels: int = 3
    iterations: tuple[int, ...] = (10, 20, 30)  # L-BFGS iterations per pyramid level, finest first
    window: int = 7
    bending: float = 1.0
    landmarks: float = 0.05
    sigma_px: float = 1.0
    flat_tau: float = 1e-4


def check_refine_config(cfg: RefineConfig) -> RefineConfig:
    """Refinement settings that can run: spacing >= 2 pixels; levels a whole number >= 1; iterations a
    whole number >= 0 or a non-empty tuple of them; window an odd whole number >= 3 pixels; bending and
    landmarks finite and >= 0; sigma_px and flat_tau positive. ValueError naming the first that is not
    (a zero sigma_px or a NaN weight crashed the process inside L-BFGS, an even window was a torch
    size mismatch)."""
    if not (np.isfinite(cfg.spacing) and cfg.spacing >= 2):
        raise ValueError(f"spacing: expected >= 2 pixels, got {cfg.spacing}")
    check_whole(cfg.levels, "levels", 1)
    its = (cfg.iterations,) if isinstance(cfg.iterations, numbers.Integral) else cfg.iterations
    if not isinstance(its, (tuple, list)) or not its or any(
            isinstance(i, bool) or not isinstance(i, numbers.Integral) or i < 0 for i in its):
        raise ValueError(f"iterations: expected a whole number >= 0 or a non-empty tuple of them (L-BFGS "
                         f"iterations per pyramid level, finest first), got {cfg.iterations!r}")
    window = cfg.window
    if isinstance(window, bool) or not isinstance(window, numbers.Integral) or window < 3 or window % 2 == 0:
        raise ValueError(f"window: expected an odd whole number >= 3 (pixels of the local NCC), got {cfg.window!r}")
    for name in ("bending", "landmarks"):  # 0 turns the term off
        check_non_negative(getattr(cfg, name), name)
    check_positive(cfg.sigma_px, "sigma_px")
    check_positive(cfg.flat_tau, "flat_tau")
    return cfg


@dataclass
class Refined:
    """Result of `refine`.

    Attributes:
        nodes: (Gy, Gx, 2) grid node pixels in the reference.
        mapped: (Gy, Gx, 2) their refined positions in the frame, pixels.
        init_cost, cost: photometric cost (1 - NCC, object average) of f0 and of the refined map at full resolution.
        jac_det: (Gy, Gx) determinant of the refined map's Jacobian at the nodes (finite differences).
        coefficients: (Gy, Gx, 2) cubic B-spline coefficients of the displacement added to f0, pixels:
            the refined map is f0 + the field `_bspline_weights` gives from them, also between the nodes.
    """

    nodes: np.ndarray
    mapped: np.ndarray
    init_cost: float
    cost: float
    jac_det: np.ndarray
    coefficients: np.ndarray


def _box(x: torch.Tensor, k: int) -> torch.Tensor:
    return F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=False)


def _bspline_weights(x: np.ndarray, x0: float, spacing: float, n: int) -> np.ndarray:
    """(len(x), n) cubic B-spline weights of nodes x0 + i * spacing at positions x (pixels)."""
    t = (np.asarray(x, float)[:, None] - (x0 + spacing * np.arange(n))[None]) / spacing
    a = np.abs(t)
    w = np.where(a < 1, 2 / 3 - a**2 + a**3 / 2, np.where(a < 2, (2 - a) ** 3 / 6, 0.0))
    return w.astype(np.float32)


class _Field:
    """Displacement field from node values: D (2, Gy, Gx) -> Wy D Wx^T on a pixel grid (cubic B-splines,
    separable, so the field of a whole level is two small matrix products)."""

    def __init__(self, xs: np.ndarray, ys: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> None:
        s = float(gx[1] - gx[0])
        self.wx = torch.from_numpy(_bspline_weights(xs, gx[0], s, len(gx)))
        self.wy = torch.from_numpy(_bspline_weights(ys, gy[0], s, len(gy)))

    def grid(self, D: torch.Tensor) -> torch.Tensor:
        """(h, w, 2) displacement on the pixel grid xs x ys."""
        return (self.wy @ D @ self.wx.T).permute(1, 2, 0)

    def points(self, D: torch.Tensor) -> torch.Tensor:
        """(N, 2) displacement at the points (xs[k], ys[k])."""
        return ((self.wy @ D) * self.wx).sum(-1).T


def _ncc_cost(level: "_Level", warped: torch.Tensor, inside: torch.Tensor, k: int, tau: float) -> torch.Tensor:
    """Weighted mean of (1 - local NCC) between the level's reference crop and `warped` (1, 1, h, w)."""
    w = level.mask
    mw = _box(w * warped, k) / level.ws
    vw = (_box(w * warped * warped, k) / level.ws - mw * mw).clamp_min(0)
    cov = _box(w * level.ref * warped, k) / level.ws - level.mr * mw
    ncc = cov / torch.sqrt(level.vr * vw + tau * tau)
    weight = level.weight * inside
    return (weight * (1 - ncc)).sum() / (weight.sum() + 1e-9)


def _level_image(img: np.ndarray, level: int) -> np.ndarray:
    for _ in range(level):
        img = cv2.pyrDown(img)
    return img


class _Level:
    """Fixed tensors of one pyramid level: the reference crop, its mask and local moments (window k),
    f0 at the crop's pixels (full-resolution pixels) and the B-spline field on them."""

    def __init__(self, ref, tgt, mask, f0: Warp, box, gx, gy, level: int, k: int, tau: float) -> None:
        x0, y0, x1, y1 = box
        s = 2**level
        ref_l = _level_image(ref, level)
        mask_l = _level_image(mask.astype(np.float32), level)
        self.tgt = torch.from_numpy(_level_image(tgt, level))[None, None]
        self.scale = s
        # cv2.pyrDown centres pixel i of a level on pixel 2 i of the level below: level pixel i lies
        # on full-resolution pixel s i (not s (i + 0.5) - 0.5, as an area resize would put it)
        lx0, ly0 = max(int(np.floor(x0 / s)), 0), max(int(np.floor(y0 / s)), 0)
        lx1 = min(int(np.ceil(x1 / s)) + 1, ref_l.shape[1])
        ly1 = min(int(np.ceil(y1 / s)) + 1, ref_l.shape[0])
        self.ref = torch.from_numpy(np.ascontiguousarray(ref_l[ly0:ly1, lx0:lx1]))[None, None]
        self.mask = torch.from_numpy(np.ascontiguousarray(mask_l[ly0:ly1, lx0:lx1] > 0.5).astype(np.float32))[None, None]
        xs = np.arange(lx0, lx1) * float(s)  # full-resolution pixel coordinates of the crop
        ys = np.arange(ly0, ly1) * float(s)
        full = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
        self.f0 = torch.from_numpy(f0(full).reshape(len(ys), len(xs), 2).astype(np.float32))
        self.field = _Field(xs, ys, gx, gy)
        self.ws = _box(self.mask, k) + 1e-6
        self.mr = _box(self.mask * self.ref, k) / self.ws
        self.vr = (_box(self.mask * self.ref * self.ref, k) / self.ws - self.mr**2).clamp_min(0)
        self.weight = self.mask * self.vr / (self.vr + tau)


def _warp(level: _Level, D: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Frame warped into the reference crop of the level and its validity (1, 1, h, w)."""
    f = level.f0 + level.field.grid(D)
    s = level.scale
    H, W = level.tgt.shape[-2:]
    xl = f[..., 0] / s  # full-resolution pixels -> this level's (`_Level`: pyrDown's pixel centres)
    yl = f[..., 1] / s
    g = torch.stack([(xl + 0.5) / W * 2 - 1, (yl + 0.5) / H * 2 - 1], dim=-1)[None]
    warped = F.grid_sample(level.tgt, g, mode="bilinear", padding_mode="border", align_corners=False)
    inside = ((xl >= 0) & (xl <= W - 1) & (yl >= 0) & (yl <= H - 1)).float()[None, None]
    return warped, inside


def _bending(D: torch.Tensor) -> torch.Tensor:
    terms = []
    if D.shape[2] >= 3:
        terms.append(((D[:, :, 2:] - 2 * D[:, :, 1:-1] + D[:, :, :-2]) ** 2).mean())
    if D.shape[1] >= 3:
        terms.append(((D[:, 2:] - 2 * D[:, 1:-1] + D[:, :-2]) ** 2).mean())
    if D.shape[1] >= 2 and D.shape[2] >= 2:
        terms.append(2 * ((D[:, 1:, 1:] - D[:, 1:, :-1] - D[:, :-1, 1:] + D[:, :-1, :-1]) ** 2).mean())
    return sum(terms) if terms else D.sum() * 0


def refine(ref: np.ndarray, tgt: np.ndarray, mask: np.ndarray, f0: Warp, lm_ref: np.ndarray, lm_tgt: np.ndarray,
           config: RefineConfig | None = None) -> Refined:
    """Refine the reference -> frame map f0 photometrically (see the module docstring).

    Args:
        ref, tgt: (H, W) float32 gray images in [0, 1] of the reference and the frame.
        mask: (H, W) bool object mask of the reference.
        f0: the landmark spline, reference -> frame pixels.
        lm_ref, lm_tgt: (L, 2) inlier landmark pixels in the reference and the frame (soft constraints).
        config: settings (`RefineConfig()` by default).
    """
    cfg = check_refine_config(config or RefineConfig())
    s = float(cfg.spacing)
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        raise ValueError("mask: the reference object mask is empty")
    H, W = ref.shape
    x0, y0, x1, y1 = xs.min(), ys.min(), xs.max(), ys.max()
    # nodes cover the object's bounding box plus one node beyond (the B-spline support)
    gx = np.arange(x0 - s, x1 + 2 * s, s)
    gy = np.arange(y0 - s, y1 + 2 * s, s)
    box = (max(int(x0 - s), 0), max(int(y0 - s), 0), min(int(x1 + s), W - 1), min(int(y1 + s), H - 1))
    # copies: a frame's read-only images (`RGBDFrame`) would become tensors torch warns of ("not writable")
    ref = np.array(ref, np.float32)
    tgt = np.array(tgt, np.float32)
    D = torch.zeros((2, len(gy), len(gx)), dtype=torch.float32, requires_grad=True)
    lm_ref = np.asarray(lm_ref, float).reshape(-1, 2)
    lm_field = _Field(lm_ref[:, 0], lm_ref[:, 1], gx, gy)
    lm_res0 = torch.from_numpy((f0(lm_ref) - np.asarray(lm_tgt, float).reshape(-1, 2)).astype(np.float32)) \
        if len(lm_ref) else torch.zeros((0, 2))

    def total(level: _Level) -> tuple[torch.Tensor, torch.Tensor]:
        warped, inside = _warp(level, D)
        photo = _ncc_cost(level, warped, inside, cfg.window, cfg.flat_tau)
        loss = photo + cfg.bending * _bending(D) / (s * s)
        if len(lm_ref):
            r = lm_res0 + lm_field.points(D)
            loss = loss + cfg.landmarks * torch.log1p((r * r).sum(-1) / cfg.sigma_px**2).mean()
        return loss, photo

    def make_level(index: int) -> _Level:
        return _Level(ref, tgt, mask, f0, box, gx, gy, index, cfg.window, cfg.flat_tau)

    full = make_level(0)
    with torch.no_grad():
        init_cost = float(total(full)[1])
    for level_index in range(cfg.levels - 1, -1, -1):
        level = full if level_index == 0 else make_level(level_index)
        its = (cfg.iterations,) if isinstance(cfg.iterations, int) else tuple(cfg.iterations)
        iters = its[min(level_index, len(its) - 1)]
        opt = torch.optim.LBFGS([D], lr=1.0, max_iter=iters, history_size=20,
                                line_search_fn="strong_wolfe", tolerance_grad=1e-7, tolerance_change=1e-9)

        def closure():
            opt.zero_grad()
            loss, _ = total(level)
            loss.backward()
            return loss

        opt.step(closure)
    with torch.no_grad():
        cost = float(total(full)[1])
    nodes = np.stack(np.meshgrid(gx, gy), axis=-1)
    with torch.no_grad():
        disp = _Field(gx, gy, gx, gy).grid(D).numpy()
    mapped = f0(nodes.reshape(-1, 2)).reshape(nodes.shape) + disp
    gyy, gxx = np.gradient(mapped, s, axis=(0, 1))
    jac = gxx[..., 0] * gyy[..., 1] - gxx[..., 1] * gyy[..., 0]
    return Refined(nodes=nodes, mapped=mapped, init_cost=init_cost, cost=cost, jac_det=jac,
                   coefficients=D.detach().numpy().transpose(1, 2, 0).astype(np.float64))
