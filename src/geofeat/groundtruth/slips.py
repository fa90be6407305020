"""Annotation slips that keep a target frame's landmarks consistent with one another, so that the
leave-one-out check (`landmarks.robust_landmark_tps`) passes them: coordinates annotated on frames of
another size (all scaled by 2 or 0.5 about the image corner, a smooth map), or ids off by one along
the annotator's order (a shift by one grid step). The spline through them then maps the frame onto
the wrong part of the reference, folding or stretching it, and was written as ground truth.

`annotation_slip` compares the image patches at the target landmarks with the reference seen through
the landmark spline (median normalised cross-correlation, NCC): for the landmarks as given and for
each slip undone. A right annotation matches best as given (a slip undone pairs other image points);
a slipped one matches better once its slip is undone.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..tps import authors_tps
from .landmarks import MIN_LANDMARKS

__all__ = ["annotation_slip", "landmark_ncc", "PATCH_RADIUS", "MIN_SLIP_GAIN", "MIN_SLIP_NCC", "SLIP_SCALES",
           "SLIP_ID_SHIFTS"]

#: Half-side of the square patches compared at each landmark, pixels (21 x 21 patches).
PATCH_RADIUS = 10
#: A frame's annotation has slipped when undoing a slip raises the median NCC at its landmarks by more
#: than MIN_SLIP_GAIN, to more than MIN_SLIP_NCC. Measured on the simulated val sequences (det2/val, 126
#: target frames): on 616 right annotations (their Harris landmarks, all, 15 or 25 of them, and a grid
#: of 30) undoing a slip raised it by at most 0.07, to at most 0.34; on 437 slipped ones (that grid
#: scaled by 2 or 0.5, its ids shifted by one with and without wrapping round) undoing the slip made
#: passed both in 394 (90 %; the others: dark, crumpled frames of the hard preset), raising it by
#: about 0.7 in the median. No frame of the ground-truth benchmark's sequences (mild deform, seeds
#: 1-3, 25 landmarks) is flagged.
MIN_SLIP_GAIN = 0.2
MIN_SLIP_NCC = 0.3
#: Scale factors tried on the target coordinates: a frame annotated at twice its size (0.5 undoes it),
#: or at half its size (2 undoes it).
SLIP_SCALES = (0.5, 2.0)
#: Id shifts tried: the target's id k taken for the reference's id k + shift.
SLIP_ID_SHIFTS = (1, -1)


def landmark_ncc(ref_image: np.ndarray, tgt_image: np.ndarray, p_ref: np.ndarray, p_tgt: np.ndarray) -> float:
    """Median NCC between the (2 PATCH_RADIUS + 1)^2 patch of `tgt_image` at each target landmark and
    the reference seen there through the landmark spline: the patch around the reference landmark,
    under the spline's local affine map (its Jacobian at the landmark; the spline interpolates the
    landmarks, so a mislabelled one spoils its own patch, not the median).

    Args:
        ref_image, tgt_image: (H, W) gray images of one size, values in [0, 1].
        p_ref, p_tgt: (N, 2) landmark pixels in the reference and the target, in the same order.
    Returns:
        the median over the landmarks of NCC in [-1, 1] (0 for a flat patch). ValueError when no
        spline fits them (`authors_tps`: fewer than 3, repeated or collinear points).
    """
    H, W = tgt_image.shape
    to_ref = authors_tps(p_tgt, p_ref, (W, H))
    dx = to_ref(p_tgt + [0.5, 0.0]) - to_ref(p_tgt - [0.5, 0.0])  # (N, 2) reference pixels per target x
    dy = to_ref(p_tgt + [0.0, 0.5]) - to_ref(p_tgt - [0.0, 0.5])
    r = np.arange(-PATCH_RADIUS, PATCH_RADIUS + 1, dtype=float)
    ox, oy = (o.ravel() for o in np.meshgrid(r, r))  # (P,) offsets, pixels
    q = (p_tgt[:, None, :] + np.stack([ox, oy], -1)[None]).astype(np.float32)  # (N, P, 2) target pixels
    m = (p_ref[:, None, :] + ox[None, :, None] * dx[:, None] + oy[None, :, None] * dy[:, None]).astype(np.float32)
    a = cv2.remap(tgt_image.astype(np.float32), q[..., 0], q[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    b = cv2.remap(ref_image.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    a, b = a - a.mean(1, keepdims=True), b - b.mean(1, keepdims=True)
    norm = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    return float(np.median(np.where(norm > 1e-9, (a * b).sum(1) / np.maximum(norm, 1e-9), 0.0)))


def _slips(ids_r: np.ndarray, xy_r: np.ndarray, ids_t: np.ndarray, xy_t: np.ndarray, shape: tuple[int, int]):
    """(description, p_ref, p_tgt) of each slip undone: the common landmarks with the target coordinates
    rescaled about the image corner (pixel centres at integers) where they stay on the image, and the
    ids re-paired with a shift."""
    H, W = shape
    _, ir, it = np.intersect1d(ids_r, ids_t, return_indices=True)
    for s in SLIP_SCALES:
        q = (xy_t[it] + 0.5) * s - 0.5
        if (q >= -0.5).all() and (q[:, 0] <= W - 0.5).all() and (q[:, 1] <= H - 0.5).all():
            size = f"{round(W / s)}x{round(H / s)}"
            yield f"its coordinates scaled by {s:g} (annotated on {size} frames?)", xy_r[ir], q
    for shift in SLIP_ID_SHIFTS:
        _, ir, it = np.intersect1d(ids_r, ids_t + shift, return_indices=True)
        if len(ir) >= MIN_LANDMARKS:
            yield f"its id k taken for the reference's id k{shift:+d} (ids off by one?)", xy_r[ir], xy_t[it]


def annotation_slip(ref_image: np.ndarray, tgt_image: np.ndarray, ids_r: np.ndarray, xy_r: np.ndarray,
                    ids_t: np.ndarray, xy_t: np.ndarray) -> str | None:
    """Why a target frame's landmarks look slipped, or None when they match best as given.

    Args:
        ref_image, tgt_image: (H, W) gray images of one size, values in [0, 1].
        ids_r, xy_r: (R,) ids and (R, 2) pixels of the reference's visible landmarks.
        ids_t, xy_t: (T,) ids and (T, 2) pixels of the target's visible landmarks.
    Returns:
        None, or a sentence naming the slip whose undoing raises `landmark_ncc` by more than
        `MIN_SLIP_GAIN` to more than `MIN_SLIP_NCC` (the highest such), with both NCCs; None too
        when no spline fits the landmarks as given (`landmark_ncc`).
    """
    _, ir, it = np.intersect1d(ids_r, ids_t, return_indices=True)
    try:
        given = landmark_ncc(ref_image, tgt_image, xy_r[ir], xy_t[it])
    except ValueError:  # no spline through the landmarks as given: nothing to compare the slips with
        return None
    best, why = max(given + MIN_SLIP_GAIN, MIN_SLIP_NCC), None
    for description, p_ref, p_tgt in _slips(ids_r, xy_r, ids_t, xy_t, tgt_image.shape):
        try:
            ncc = landmark_ncc(ref_image, tgt_image, p_ref, p_tgt)
        except ValueError:  # no spline through the re-paired landmarks: not this slip
            continue
        if ncc > best:
            best, why = ncc, (f"the image at the landmarks matches the reference with {description}: median "
                              f"NCC {ncc:.2f}, against {given:.2f} as given")
    return why
