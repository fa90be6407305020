"""Dense ground truth for an annotated sequence: landmarks -> robust spline -> photometric refinement
-> the authors' TPS files, a per-frame quality report and overlay pictures.

Output folder (one per sequence, read by `geofeat bench --tps-dir`):
    `<frame>_objmask.png`   every frame, reference included: 255 on the object, else 0,
    `<k>_theta.npy`         (1, T+3, 2) float32, `<k>_ctrlpts.npy` (T, 2) float32: the target -> reference
                            spline of target frame k in the authors' parametrisation (`geofeat.tps.authors_tps`),
    `<k>_SSIM.png`          SSIM (x 255) between frame k and the reference warped into it, 0 off the object;
                            the bench keeps target keypoints where it is > 0.25 (occluded or misregistered
                            parts fall below),
    `<k>_overlay.png`       frame k with the refined control-point grid and the landmarks, next to a
                            checkerboard of frame k and the warped reference,
    `report.csv`, `report.json`  per frame: status, landmarks (used, rejected, residuals), SSIM before and
                            after refinement, photometric cost, control points, seconds.
A frame that fails (too few landmarks, landmarks that disagree, unreadable, another size than the
reference, refinement diverged) gets no TPS files and status `failed` with
the reason; the others are written.
"""

from __future__ import annotations

import csv
import json
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from ..frame import RGBDFrame
from ..imagequality import ssim_map
from ..constants import DEPTH_SCALE_M
from ..inputs import check_landmarks, read_config
from ..io import RGB_SUFFIX, Sequence, read_image, read_landmarks, read_sequence, sequence_digest
from ..outputs import GROUND_TRUTH, check_out_dir, json_text, output_folder, read_manifest, write_picture
from .defaults import DEFAULT_DEPTH_MARGIN_M, DEFAULT_MARGIN_PX, DEFAULT_SPACING_PX
from .photometric import RefineConfig, check_refine_config, refine
from ..tps import ThinPlateSpline, authors_tps, spans_plane
from .landmarks import MIN_LANDMARKS, robust_landmark_tps
from .slips import annotation_slip

#: The bench keeps target keypoints where the SSIM map exceeds this.
SSIM_KEEP = 0.25
#: Divergence tests of a refined frame.
MAX_COST_RISE = 0.02
MAX_SSIM_DROP = 0.02
MAX_FOLDED_FRACTION = 0.05
MAX_LANDMARK_MEDIAN_PX = 3.0
#: A frame fails when the spline through the other landmarks misses its median landmark by more than
#: this many pixels: most of its landmarks disagree with one another (ids that name other points than in
#: the reference). Simulated frames stay below 5 px; a frame with its ids shuffled was written as "ok".
MAX_LOO_MEDIAN_PX = 25.0
#: A landmark is off the object when a gap of more than twice the depth margin and this many robust
#: standard deviations of the landmarks' depths cuts its depth off from the object's
#: (`off_object_landmarks`). Simulated deformations leave gaps of up to 0.22 m between the depths of
#: neighbouring landmarks (val sequences, 10-25 landmarks kept), under the 0.3 m of the default margin.
OFF_OBJECT_SIGMAS = 3.0


@dataclass
class GroundTruthConfig:
    """Settings of `generate_ground_truth`.

    Attributes:
        refine: photometric refinement (False: the landmark-only spline).
        spacing: control-point spacing in reference pixels.
        margin_px: the reference object mask reaches this far (pixels) beyond the landmarks' convex hull.
        depth_margin_m: ... and keeps depths within this many metres of the landmarks' depth range
            (pixels without depth are off the object).
        refine_config: further refinement settings (its `spacing` is overridden by `spacing`).
    """

    refine: bool = True
    spacing: float = DEFAULT_SPACING_PX
    margin_px: float = DEFAULT_MARGIN_PX
    depth_margin_m: float = DEFAULT_DEPTH_MARGIN_M
    refine_config: RefineConfig = field(default_factory=RefineConfig)


@dataclass
class FrameReport:
    """Quality of one target frame's ground truth (pixels, SSIM on 0..1, seconds)."""

    frame: str
    status: str = "ok"
    reason: str = ""
    landmarks: int = 0
    inliers: int = 0
    rejected_ids: list = field(default_factory=list)
    loo_median_px: float = float("nan")
    landmark_median_px: float = float("nan")
    landmark_max_px: float = float("nan")
    ssim_before: float = float("nan")
    ssim_after: float = float("nan")
    cost_before: float = float("nan")
    cost_after: float = float("nan")
    ctrlpts: int = 0
    seconds: float = 0.0


def _frame_shape(seq: Sequence, name: str) -> tuple[int, int] | None:
    """(H, W) of frame `name`'s colour image; None when it cannot be read (`_frame` then fails it)."""
    try:
        return read_image(seq.folder / f"{name}{RGB_SUFFIX}").shape[:2]
    except ValueError:
        return None


def _valid_landmarks(seq: Sequence, shape: tuple[int, int]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Every frame's (ids, xy, visible), checked: csv present, ids unique, visible rows on the image
    (the reference's (H, W) `shape`, or a target's own size when it differs: `_frame` fails that
    frame, naming both sizes), target ids known in the reference."""
    out = {}
    for name in seq.names:
        if not (seq.folder / f"{name}.csv").is_file():
            raise ValueError(f"sequence {seq.name}: frame {name} has no landmark csv ({name}.csv); "
                             "ground truth needs landmarks in every frame")
        ids, xy, vis = read_landmarks(seq.folder / f"{name}.csv")
        try:
            check_landmarks(ids, xy, vis, shape, f"{name}.csv")  # the one landmark validator
        except ValueError:
            # a larger target's landmarks lie off the reference's image: this stopped the whole run,
            # saying they were off a "640x480 image" the frame is not
            own = None if name == seq.reference else _frame_shape(seq, name)
            if own is None or own == tuple(shape):
                raise
            check_landmarks(ids, xy, vis, own, f"{name}.csv")
        out[name] = (ids, xy, vis)
    ref_ids = out[seq.reference][0]
    for name in seq.targets:
        unknown = np.setdiff1d(out[name][0], ref_ids)
        if len(unknown):
            raise ValueError(f"landmarks: {name}.csv has ids missing from the reference csv "
                             f"({seq.reference}.csv): {unknown[:10].tolist()}")
    if out[seq.reference][2].sum() < MIN_LANDMARKS:
        raise ValueError(f"landmarks: the reference {seq.reference} has {out[seq.reference][2].sum()} visible landmarks, "
                         f"a spline needs >= {MIN_LANDMARKS}")
    _, ref_xy, ref_vis = out[seq.reference]
    if not spans_plane(ref_xy[ref_vis]):  # every frame failed on it, as "src: the points are collinear"
        raise ValueError(f"landmarks: the {ref_vis.sum()} visible landmarks of the reference {seq.reference} lie on "
                         "one line (or on one point); a spline needs landmarks spanning the plane")
    return out


def _hull_distance(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) distance in pixels to the convex hull of the (N, 2) pixels `points` (0 inside), the hull's
    corners at the nearest pixels (pixel centres at integers; truncating left a landmark at 20.9 outside
    the hull drawn through pixel 20)."""
    hull = np.rint(cv2.convexHull(points.astype(np.float32))).astype(np.int32)
    inside = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    return cv2.distanceTransform((1 - inside).astype(np.uint8), cv2.DIST_L2, 5)


def _depth_ok(frame: RGBDFrame, zmin: float, zmax: float) -> np.ndarray:
    return (frame.depth > 0) & (frame.depth >= zmin) & (frame.depth <= zmax)


def _landmark_depths(frame: RGBDFrame, xy: np.ndarray) -> np.ndarray:
    """(N,) depth in metres at the pixel nearest to each of the (N, 2) pixels `xy` (clipped to the
    image); 0 where the depth is missing."""
    H, W = frame.shape
    return frame.depth[np.clip(np.rint(xy[:, 1]).astype(int), 0, H - 1), np.clip(np.rint(xy[:, 0]).astype(int), 0, W - 1)]


def _depth_range(frame: RGBDFrame, xy: np.ndarray, margin: float) -> tuple[float, float]:
    z = _landmark_depths(frame, xy)
    z = z[z > 0]
    if len(z) == 0:  # no depth at the landmarks: depth does not restrict the mask
        return 0.0, np.inf
    return float(z.min() - margin), float(z.max() + margin)


def off_object_landmarks(frame: RGBDFrame, xy: np.ndarray, depth_margin_m: float) -> np.ndarray:
    """(N,) bool: which of the (N, 2) landmark pixels `xy` lie at a depth cut off from the object's, as a
    click just off the cloth, on the wall behind it, does. Sorted, the landmarks' depths split into
    runs wherever two neighbours differ by more than 2 `depth_margin_m` metres and `OFF_OBJECT_SIGMAS`
    robust standard deviations of the depths (1.4826 x their median absolute deviation); the largest
    run (the nearest of equally large ones) is the object, the other runs are off it. A click on a
    table just below the cloth stays (its depth is the object's, within the margins). Landmarks without
    depth, and all of them when fewer than 3 have depth, are not judged (False)."""
    z = _landmark_depths(frame, xy)
    has = z > 0
    off = np.zeros(len(z), bool)
    if has.sum() < 3:
        return off
    d = z[has]
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    order = np.argsort(d, kind="stable")
    run = np.concatenate([[0], np.cumsum(np.diff(d[order]) > max(2 * depth_margin_m, OFF_OBJECT_SIGMAS * sigma))])
    off_sorted = run != int(np.argmax(np.bincount(run)))  # argmax: the first, nearest, of equally large runs
    off[np.flatnonzero(has)[order]] = off_sorted
    return off


def _warn_off_object(frame: RGBDFrame, name: str, ids: np.ndarray, xy: np.ndarray, depth_margin_m: float,
                     known: np.ndarray | None = None) -> np.ndarray:
    """`off_object_landmarks` of frame `name` (landmark ids (N,), pixels xy (N, 2)), with a warning
    naming the frame and the ids it finds, those in `known` (already named for the reference) left out."""
    off = off_object_landmarks(frame, xy, depth_margin_m)
    new = off & ~np.isin(ids, [] if known is None else known)
    if new.any():
        z = _landmark_depths(frame, xy)
        on = ~off & (z > 0)
        warnings.warn(f"landmarks: {name}.csv ids {ids[new].tolist()} lie at depth "
                      f"{', '.join(f'{v:.2f}' for v in z[new])} m, cut off from the other landmarks' "
                      f"{z[on].min():.2f}-{z[on].max():.2f} m (clicks off the object, on the wall behind "
                      "it?); they are left out of the object mask", stacklevel=3)
    return off


def reference_mask(frame: RGBDFrame, landmarks: np.ndarray, margin_px: float, depth_margin_m: float) -> np.ndarray:
    """(H, W) bool object mask of the reference: within `margin_px` of the landmarks' hull, with depth
    inside the landmarks' depth range widened by `depth_margin_m` metres; landmarks at a depth cut off
    from the object's (`off_object_landmarks`: a click on the background) are left out of both, which
    they widened over the background."""
    landmarks = landmarks[~off_object_landmarks(frame, landmarks, depth_margin_m)]
    mask = _hull_distance(landmarks, frame.shape) <= margin_px
    zmin, zmax = _depth_range(frame, landmarks, depth_margin_m)
    return mask & _depth_ok(frame, zmin, zmax) if np.isfinite(zmax) else mask


def _dense_map(tps: ThinPlateSpline, shape: tuple[int, int], stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The spline at every pixel (H, W) x 2 float32 maps, evaluated every `stride` pixels and
    interpolated bilinearly in between (the spline is smooth at that scale)."""
    H, W = shape
    xs = np.arange(0, W + stride, stride, dtype=float)
    ys = np.arange(0, H + stride, stride, dtype=float)
    gx, gy = np.meshgrid(xs, ys)
    m = tps(np.stack([gx.ravel(), gy.ravel()], 1)).reshape(len(ys), len(xs), 2).astype(np.float32)
    px, py = np.meshgrid(np.arange(W, dtype=np.float32) / stride, np.arange(H, dtype=np.float32) / stride)
    mx = cv2.remap(m[..., 0], px, py, cv2.INTER_LINEAR)
    my = cv2.remap(m[..., 1], px, py, cv2.INTER_LINEAR)
    return mx, my


@dataclass
class _Warped:
    mask: np.ndarray  # (H, W) bool target object mask
    ssim: np.ndarray  # (H, W) float32 SSIM, 0 off the mask
    warped: np.ndarray  # (H, W) reference warped into the target


def _evaluate(tps_inv: ThinPlateSpline, ref: RGBDFrame, ref_mask: np.ndarray, tgt: RGBDFrame, zrange) -> _Warped:
    mx, my = _dense_map(tps_inv, tgt.shape)
    warped = cv2.remap(ref.image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    on_ref = cv2.remap(ref_mask.astype(np.uint8), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=0) > 0
    mask = on_ref & (_depth_ok(tgt, *zrange) if np.isfinite(zrange[1]) else True)
    ssim = np.clip(ssim_map(tgt.image, warped), 0, 1) * mask
    return _Warped(mask=mask, ssim=ssim.astype(np.float32), warped=warped)


def _overlay(tgt: RGBDFrame, ev: _Warped, lines: np.ndarray | None, lm_in: np.ndarray, lm_out: np.ndarray) -> np.ndarray:
    """Frame with the control-point grid (red) and landmarks (green inliers, red rejected), keyed in
    its top-left corner, next to a checkerboard of the frame and the warped reference (object only).
    Returns an (h, 2 w, 3) uint8 BGR image: (H, 2 W) for frames of W pixels, or less when 2 W exceeds
    `viz.MAX_PICTURE_WIDTH`: both halves are then shrunk to fit it, the grid and landmarks with them."""
    from ..viz import picture_scale, put_label, shrink_image, shrink_points

    gray = (tgt.image * 255).astype(np.uint8)
    H, W = gray.shape
    shrink = picture_scale(2 * W)
    yy, xx = np.mgrid[0:H, 0:W]
    cell = max(1, round(24 / shrink))  # 24 pixels of the picture
    checker = ((yy // cell + xx // cell) % 2 == 0) & ev.mask
    right = np.where(checker, (ev.warped * 255).astype(np.uint8), gray)
    if shrink < 1:  # a huge frame: the picture at most MAX_PICTURE_WIDTH wide, as the match pictures
        (gray, scale), (right, _) = shrink_image(gray, shrink), shrink_image(right, shrink)
        lines = None if lines is None else shrink_points(lines, scale)
        lm_in, lm_out = shrink_points(lm_in, scale), shrink_points(lm_out, scale)
    left = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    if lines is not None:
        for a, b in lines:
            cv2.line(left, tuple(np.rint(a).astype(int)), tuple(np.rint(b).astype(int)), (0, 0, 230), 1, cv2.LINE_AA)
    for x, y in lm_in:
        cv2.circle(left, (int(round(x)), int(round(y))), 4, (0, 220, 0), 2, cv2.LINE_AA)
    for x, y in lm_out:
        cv2.drawMarker(left, (int(round(x)), int(round(y))), (0, 0, 255), cv2.MARKER_TILTED_CROSS, 12, 2)
    right = cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)
    y = put_label(left, "red grid: control points", (4, 4), 0.45, (80, 80, 255))[3]
    y = put_label(left, f"landmarks: {len(lm_in)} inliers (green o)", (4, y), 0.45, (0, 220, 0))[3]
    if len(lm_out):
        put_label(left, f"{len(lm_out)} rejected (red x)", (4, y), 0.45, (80, 80, 255))
    put_label(right, "checkerboard: frame / warped reference", (4, 4), 0.45, (0, 255, 255))
    return np.concatenate([left, right], axis=1)


def _grid_lines(mapped: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(M, 2, 2) segments between horizontally or vertically adjacent kept nodes."""
    segs = []
    h = keep[:, 1:] & keep[:, :-1]
    segs.append(np.stack([mapped[:, :-1][h], mapped[:, 1:][h]], axis=1))
    v = keep[1:] & keep[:-1]
    segs.append(np.stack([mapped[:-1][v], mapped[1:][v]], axis=1))
    return np.concatenate(segs)


def _nodes_near_object(refined, ref_mask: np.ndarray, spacing: float, shape) -> np.ndarray:
    """(Gy, Gx) bool: nodes near the object (within one spacing of the mask) and mapped near the frame."""
    H, W = shape
    near = cv2.dilate(ref_mask.astype(np.uint8), cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * int(spacing) + 1, 2 * int(spacing) + 1))) > 0
    n = refined.nodes
    ix = np.clip(np.rint(n[..., 0]).astype(int), 0, W - 1)
    iy = np.clip(np.rint(n[..., 1]).astype(int), 0, H - 1)
    inside = (n[..., 0] >= -0.5) & (n[..., 0] <= W - 0.5) & (n[..., 1] >= -0.5) & (n[..., 1] <= H - 0.5)
    m = refined.mapped
    in_frame = (m[..., 0] > -2 * spacing) & (m[..., 0] < W + 2 * spacing) & (m[..., 1] > -2 * spacing) & (m[..., 1] < H + 2 * spacing)
    return inside & near[iy, ix] & in_frame


def _write_frame(out: Path, name: str, tps_inv: ThinPlateSpline, ev: _Warped) -> None:
    theta, ctrl = tps_inv.authors_arrays()
    np.save(out / f"{name}_theta.npy", theta)
    np.save(out / f"{name}_ctrlpts.npy", ctrl)
    write_picture(out / f"{name}_objmask.png", ev.mask.astype(np.uint8) * 255)
    write_picture(out / f"{name}_SSIM.png", np.rint(ev.ssim * 255).astype(np.uint8))


def _frame(seq: Sequence, name: str, ref: RGBDFrame, ref_mask: np.ndarray, lms: dict, config: GroundTruthConfig,
           out: Path) -> FrameReport:
    """Ground truth of target frame `name`: a robust spline through the landmarks both frames see,
    optionally refined photometrically, judged (`_refinement_failures`, `_not_finite`) and, when
    good, written to `out` (`_write_frame`, and `<name>_overlay.png`).

    Args:
        ref: the reference frame; ref_mask: its (H, W) bool object mask.
        lms: {frame name: (ids (L,), xy (L, 2) pixels, visible (L,) bool)} of every frame.
    Returns:
        the frame's `FrameReport` (status "failed" with a reason when no ground truth was written).
    """
    t0 = time.perf_counter()
    rep = FrameReport(frame=name)
    ids_r, xy_r, vis_r = lms[seq.reference]
    ids_t, xy_t, vis_t = lms[name]
    common, ir, it = np.intersect1d(ids_r[vis_r], ids_t[vis_t], return_indices=True)
    rep.landmarks = len(common)
    if len(common) < MIN_LANDMARKS:
        rep.status, rep.reason = "failed", f"{len(common)} landmarks visible in both frames, a spline needs >= {MIN_LANDMARKS}"
        return rep
    p_ref, p_tgt = xy_r[vis_r][ir], xy_t[vis_t][it]
    flat = [which for which, xy in (("the reference", p_ref), ("this frame", p_tgt)) if not spans_plane(xy)]
    if flat:
        rep.status, rep.reason = "failed", (f"the {len(common)} landmarks visible in both frames lie on one line (or "
                                            f"on one point) in {' and '.join(flat)}; a spline needs landmarks "
                                            "spanning the plane")
        return rep
    try:
        tgt = seq.frame(name)
    except ValueError as error:  # unreadable colour, no usable depth: this frame fails, the others go on
        rep.status, rep.reason = "failed", f"the frame cannot be read ({' '.join(str(error).split())})"
        return rep
    if tgt.shape != ref.shape:  # the spline and the landmark check assume the reference's image size
        rep.status, rep.reason = "failed", (f"the frame is {tgt.shape[1]}x{tgt.shape[0]}, the reference "
                                            f"{ref.shape[1]}x{ref.shape[0]}")
        return rep
    size = (ref.shape[1], ref.shape[0])
    try:
        fit = robust_landmark_tps(p_ref, p_tgt, size)
        inl = fit.inliers
        lm_inv = authors_tps(p_tgt[inl], p_ref[inl], size)
    except ValueError as error:
        rep.status, rep.reason = "failed", f"the landmark spline cannot be fitted ({error})"
        return rep
    # the target's own depth range: the object moves in depth (a camera moving back, another renderer's
    # units and scene scale), so the reference's range would empty the target mask and make SSIM NaN
    ref_off = ids_r[vis_r][off_object_landmarks(ref, xy_r[vis_r], config.depth_margin_m)]  # named by `check_sequence`
    off = _warn_off_object(tgt, name, common[inl], p_tgt[inl], config.depth_margin_m, known=ref_off)
    zrange = _depth_range(tgt, p_tgt[inl][~off], config.depth_margin_m)
    rep.inliers = int(inl.sum())
    rep.rejected_ids = common[~inl].tolist()
    rep.loo_median_px = float(np.nanmedian(fit.loo_px))
    if rep.loo_median_px > MAX_LOO_MEDIAN_PX:  # before the refinement, which failed such a frame as "diverged"
        rep.status, rep.reason = "failed", (
            f"the landmarks disagree: the spline through the others misses the median landmark by "
            f"{rep.loo_median_px:.1f} px (leave-one-out, > {MAX_LOO_MEDIAN_PX:g} px); do the ids of {name}.csv "
            f"name the same points as those of {seq.reference}.csv?")
        rep.seconds = time.perf_counter() - t0
        return rep
    # landmarks that agree with one another but not with the image: another resolution, ids off by one
    slip = annotation_slip(ref.image, tgt.image, ids_r[vis_r], xy_r[vis_r], ids_t[vis_t], xy_t[vis_t])
    if slip:
        rep.status, rep.reason = "failed", f"{name}.csv looks slipped: {slip}"
        rep.seconds = time.perf_counter() - t0
        return rep
    before = _evaluate(lm_inv, ref, ref_mask, tgt, zrange)
    tps_inv, lines, ev = lm_inv, None, before
    if config.refine:
        rcfg = RefineConfig(**{**asdict(config.refine_config), "spacing": config.spacing})
        r = refine(ref.image, tgt.image, ref_mask, fit.tps, p_ref[inl], p_tgt[inl], rcfg)
        rep.cost_before, rep.cost_after = r.init_cost, r.cost
        near = _nodes_near_object(r, ref_mask, config.spacing, ref.shape)
        keep = near & (r.jac_det > 0.1)  # folded or crushed nodes would make the inverse ill-posed
        folded = float((near & (r.jac_det <= 0)).sum() / max(near.sum(), 1))
        try:
            tps_inv = authors_tps(r.mapped[keep], r.nodes[keep], size)
        except ValueError as error:
            rep.status, rep.reason = "failed", f"refinement diverged: {error}"
            rep.seconds = time.perf_counter() - t0  # the refinement it ran
            return rep
        ev = _evaluate(tps_inv, ref, ref_mask, tgt, zrange)
        lines = _grid_lines(r.mapped, keep)
        rep.ctrlpts = int(keep.sum())
    else:
        rep.ctrlpts = int(inl.sum())
    res = np.linalg.norm(tps_inv(p_tgt[inl]) - p_ref[inl], axis=1)
    rep.landmark_median_px, rep.landmark_max_px = float(np.median(res)), float(res.max())
    common_mask = ev.mask & before.mask
    if not common_mask.any():
        rep.status, rep.reason = "failed", "the object mask of the frame is empty (no pixel to judge the alignment on)"
        rep.seconds = time.perf_counter() - t0
        return rep
    rep.ssim_before = float(before.ssim[common_mask].mean())
    rep.ssim_after = float(ev.ssim[common_mask].mean())
    reasons = _refinement_failures(rep, folded) if config.refine else []
    if reasons:
        rep.status, rep.reason = "failed", "refinement diverged: " + "; ".join(reasons)
        rep.seconds = time.perf_counter() - t0
        return rep
    not_finite = _not_finite(rep, config.refine)
    if not_finite:  # a NaN in a report is a failure, never "ok"
        rep.status, rep.reason = "failed", f"not finite: {', '.join(not_finite)}"
        rep.seconds = time.perf_counter() - t0
        return rep
    _write_frame(out, name, tps_inv, ev)
    write_picture(out / f"{name}_overlay.png", _overlay(tgt, ev, lines, p_tgt[inl], p_tgt[~inl]))
    rep.seconds = time.perf_counter() - t0
    return rep


def _refinement_failures(rep: FrameReport, folded: float) -> list[str]:
    """Why a refined frame is rejected ([] when it is kept): the photometric cost rose by more than
    MAX_COST_RISE, SSIM fell by more than MAX_SSIM_DROP, the map folds over at more than
    MAX_FOLDED_FRACTION of the control points near the object (`folded`, a fraction), or the landmark
    residuals' median exceeds MAX_LANDMARK_MEDIAN_PX pixels."""
    reasons = []
    if rep.cost_after > rep.cost_before + MAX_COST_RISE:
        reasons.append(f"photometric cost rose {rep.cost_before:.3f} -> {rep.cost_after:.3f}")
    if rep.ssim_after < rep.ssim_before - MAX_SSIM_DROP:
        reasons.append(f"SSIM fell {rep.ssim_before:.3f} -> {rep.ssim_after:.3f}")
    if folded > MAX_FOLDED_FRACTION:
        reasons.append(f"the map folds over at {folded:.0%} of the control points")
    if rep.landmark_median_px > MAX_LANDMARK_MEDIAN_PX:
        reasons.append(f"landmark residuals median {rep.landmark_median_px:.1f} px > {MAX_LANDMARK_MEDIAN_PX} px")
    return reasons


def _not_finite(rep: FrameReport, refined: bool) -> list[str]:
    """Names of the report's float figures that are NaN or infinite (the photometric costs only when
    the frame was `refined`)."""
    numbers = {k: v for k, v in asdict(rep).items() if isinstance(v, float) and k not in ("cost_before", "cost_after")}
    if refined:
        numbers.update(cost_before=rep.cost_before, cost_after=rep.cost_after)
    return [k for k, v in numbers.items() if not np.isfinite(v)]


def generate_ground_truth(sequence: str | Path | Sequence, out: str | Path, config: GroundTruthConfig | None = None,
                          progress: bool = True, overwrite: bool = False) -> list[FrameReport]:
    """Dense ground truth of one annotated sequence, written to the folder `out` (see the module docstring).

    Args:
        sequence: a sequence folder in the public layout with a landmark csv per frame, or a `Sequence`
            (`read_sequence(folder, depth_scale=...)` for depth PNGs in other units than geofeat.json says).
        out: output folder (created; built aside and moved into place at the end; an existing non-empty
            folder needs `overwrite`, which replaces only what geofeat wrote there); the bench reads it as `--tps-dir` when it is named like the sequence
            or sits in a folder given as `--tps-dir`.
        config: settings (`GroundTruthConfig()` by default).
    Returns:
        one FrameReport per target frame (also in out/report.csv and out/report.json).
    Raises:
        ValueError: `check_sequence` (a single frame, an unreadable reference, bad landmark files:
            missing, repeated ids, visible rows off the image, ids unknown to the reference, fewer than 4
            visible in the reference), bad settings, an existing output. A target frame that cannot be
            read or differs from the reference in size is a failed frame, not an error.
    """
    config = config or GroundTruthConfig()
    check_config(config)
    seq = sequence if isinstance(sequence, Sequence) else read_sequence(sequence)
    ref, lms, ref_mask = check_sequence(seq, config)
    out = check_out_dir(out, overwrite, files=result_files(seq), inputs=[seq.folder], writes=GROUND_TRUTH)
    names = seq.targets
    if progress:
        from tqdm import tqdm

        names = tqdm(names, desc=f"groundtruth {seq.name}", unit="frame")
    with output_folder(out) as tmp:
        write_picture(tmp / f"{seq.reference}_objmask.png", ref_mask.astype(np.uint8) * 255)
        reports = [_frame(seq, name, ref, ref_mask, lms, config, tmp) for name in names]
        _write_report(tmp, seq, config, reports)
    return reports


def result_files(seq: Sequence) -> list[str]:
    """Names of the files `generate_ground_truth` may write into its output folder for `seq` (see the
    module docstring), for `check_out_dir` to refuse, before any work, replacing one geofeat did not write."""
    per_target = ("_theta.npy", "_ctrlpts.npy", "_objmask.png", "_SSIM.png", "_overlay.png")
    return [f"{seq.reference}_objmask.png", "report.csv", "report.json",
            *(f"{name}{suffix}" for name in seq.targets for suffix in per_target)]


def check_sequence(seq: Sequence, config: GroundTruthConfig) -> tuple[RGBDFrame, dict, np.ndarray]:
    """Every input check of one sequence, before any work: a reference and at least one target, a
    usable reference frame, settings that fit its size, valid landmark files (`_valid_landmarks`) and
    a non-empty reference object mask. Returns (reference frame, {frame: (ids, xy, visible)}, mask);
    ValueError naming the sequence (or file) otherwise."""
    if len(seq) < 2:
        raise ValueError(f"sequence {seq.name}: needs a reference and at least one target frame")
    try:
        ref = seq.frame(seq.reference)
    except ValueError as error:
        raise ValueError(f"sequence {seq.name}: the reference frame {seq.reference} cannot be used "
                         f"({' '.join(str(error).split())})") from None
    check_config(config, ref.shape)
    lms = _valid_landmarks(seq, ref.shape)
    ids_r, xy_r, vis_r = lms[seq.reference]
    _warn_off_object(ref, seq.reference, ids_r[vis_r], xy_r[vis_r], config.depth_margin_m)
    ref_mask = reference_mask(ref, xy_r[vis_r], config.margin_px, config.depth_margin_m)
    if not ref_mask.any():
        raise ValueError(f"sequence {seq.name}: the reference object mask is empty (landmarks without depth in "
                         f"range, or --margin {config.margin_px:g} too small)")
    return ref, lms, ref_mask


def check_config(config: GroundTruthConfig, shape: tuple[int, int] | None = None) -> None:
    """Settings must be finite, margins >= 0, the spacing >= 2 pixels and (with the frame's (H, W))
    at most half the smaller image side: a grid needs control points inside the frame; the
    refinement settings must run (`check_refine_config`)."""
    for key in ("spacing", "margin_px", "depth_margin_m"):
        value = getattr(config, key)
        if not np.isfinite(value):
            raise ValueError(f"{key}: expected a finite number, got {value}")
    if config.margin_px < 0:
        raise ValueError(f"margin: expected >= 0 pixels beyond the landmarks' hull, got {config.margin_px:g}")
    if config.depth_margin_m < 0:
        raise ValueError(f"depth-margin: expected >= 0 metres, got {config.depth_margin_m:g}")
    if config.spacing < 2:
        raise ValueError(f"spacing: expected >= 2 pixels, got {config.spacing}")
    if shape is not None and config.spacing > min(shape) / 2:
        raise ValueError(f"spacing: {config.spacing:g} pixels leaves no control-point grid on a {shape[1]}x{shape[0]} "
                         f"frame; expected 2-{min(shape) / 2:g}")
    check_refine_config(replace(config.refine_config, spacing=config.spacing))


def _write_report(out: Path, seq: Sequence, config: GroundTruthConfig, reports: list[FrameReport]) -> None:
    rows = [asdict(r) for r in reports]
    with open(out / "report.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, list(rows[0].keys()) if rows else ["frame"])
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (" ".join(map(str, v)) if isinstance(v, list) else v) for k, v in row.items()})
    # a failed frame's figures: null, not NaN (`json_text`)
    (out / "report.json").write_text(json_text(
        # the folder in full: `finished_result` compares it with the folder a --resume run names (the
        # same sequence given as "seq" here and "/data/seq" there was refused as another sequence)
        {"sequence": str(Path(seq.folder).resolve()), "sequence_digest": sequence_digest(seq.folder), "reference": seq.reference,
         "depth_scale": seq.depth_scale, "config": asdict(config), "frames": rows}, indent=1, default=float),
        encoding="utf-8")


def _same_folder(recorded, folder: Path) -> bool:
    """Whether the folder `recorded` in a report.json (a path, relative ones as an older geofeat wrote
    them, read from the working folder) is `folder`, however each is spelled."""
    return isinstance(recorded, str) and Path(recorded).resolve() == Path(folder).resolve()


def finished_result(out: str | Path, seq: Sequence, config: GroundTruthConfig) -> bool:
    """Whether the folder `out` holds this sequence's finished ground truth made with `config` (its
    report.json, written last and listed in the folder's manifest, names the same sequence folder, the
    same files (`io.sequence_digest`), the same depth scale (`seq.depth_scale`) and the same settings):
    `geofeat groundtruth --resume` skips it.
    False when `out` holds no finished result. ValueError, naming what differs, when it holds one made
    from another sequence, from files changed since, at another depth scale or with other settings, or
    one whose files are not all there (a run killed while moving them in left report.json without the
    frames' files)."""
    out = Path(out)
    report = out / "report.json"
    listed = read_manifest(out)
    if not report.is_file() or "report.json" not in listed:
        return False
    missing = [rel for rel in listed if not (out / rel).is_file()]
    if missing:  # a run killed while `replace_folder` moved its files in (report.json sorts before "view-001_...")
        raise ValueError(f"--out: {out} holds ground truth that --resume cannot keep: {', '.join(missing[:3])}"
                         f"{', ...' if len(missing) > 3 else ''} listed there but missing (a run stopped while "
                         "writing it?); use --overwrite to make it again")
    try:
        made = json.loads(report.read_text(encoding="utf-8"))
    except ValueError:
        raise ValueError(f"--out: {report} is not valid JSON; use --overwrite to make {out} again") from None
    differences = []
    if not isinstance(made, dict) or not _same_folder(made.get("sequence"), seq.folder):
        differences.append(f"it was made from {made.get('sequence') if isinstance(made, dict) else '?'}, "
                           f"not {seq.folder}")
    elif made.get("sequence_digest") not in (None, sequence_digest(seq.folder)):
        differences.append("the sequence's frames or landmarks changed since")
    # the object mask keeps depths within metres of the landmarks': a --depth-scale changes it; a report
    # without one was made at the folder's own scale (its geofeat.json's, which the digest covers)
    own = read_config(seq.folder).get("depth_scale", DEPTH_SCALE_M)
    scale = made.get("depth_scale", own) if isinstance(made, dict) else None
    if scale != seq.depth_scale and not differences:
        differences.append(f"another depth scale ({scale} m per unit there, {seq.depth_scale:g} now)")
    there = made.get("config") if isinstance(made, dict) else None
    now = json.loads(json_text(asdict(config)))  # as report.json holds it: lists for tuples, null for NaN
    if there != now and not differences:
        changed = sorted(k for k in now if (there or {}).get(k) != now[k])
        differences.append(f"other settings ({', '.join(changed) or 'all'})")
    if differences:
        raise ValueError(f"--out: {out} holds ground truth that --resume cannot keep: {'; '.join(differences)}; use "
                         "--overwrite to make it again")
    return True
