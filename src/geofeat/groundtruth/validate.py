"""Check generated ground truth against a simulated sequence's exact correspondences.

`keep_landmarks` copies a simulated sequence keeping only some landmark rows (as a person would
annotate a few points); `mapping_errors` compares the target -> reference mapping of a TPS folder with
the simulator's exact one at object pixels, split by the landmarks' convex hull.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .landmarks import inside_hull
from .sources import load_authors_spline
from ..inputs import check_whole
from ..io import Sequence, read_sequence, write_landmarks
from ..outputs import SEQUENCE, check_out_dir


def keep_landmarks(sequence: str | Path, out: str | Path, n: int, seed: int = 0) -> Path:
    """Copy a sequence folder to `out` (which must not exist or be empty) keeping `n` landmark ids (drawn with `seed` among the ids visible
    in the reference) in every csv; the other rows are dropped. Returns `out`."""
    seq = read_sequence(sequence)
    ids, _, vis = seq.landmarks(seq.reference)
    if n < 1 or n > vis.sum():
        raise ValueError(f"n: expected 1..{vis.sum()} (landmarks visible in the reference), got {n}")
    keep = np.random.default_rng(seed).choice(ids[vis], size=n, replace=False)
    out = check_out_dir(out, what="out", writes=SEQUENCE)  # never deletes an existing folder
    if out.exists():
        out.rmdir()  # empty
    shutil.copytree(seq.folder, out)
    for name in seq.names:
        i, xy, v = seq.landmarks(name)
        sel = np.isin(i, keep)
        write_landmarks(out / f"{name}.csv", i[sel], np.where(v[sel, None], xy[sel], -1.0), v[sel])
    return out


@dataclass
class MappingErrors:
    """Errors (pixels) of one frame's target -> reference mapping at object pixels visible in both
    frames, inside and outside the convex hull of the target landmarks visible in both frames."""

    frame: str
    inside: np.ndarray
    outside: np.ndarray


def mapping_errors(seq: Sequence, tps_folder: str | Path, target: str, stride: int = 4) -> MappingErrors:
    """Compare `<target>_theta.npy` / `_ctrlpts.npy` in `tps_folder` with the exact ground truth of a
    simulated `seq` on a pixel grid of `stride` pixels over the target frame (points on the object in
    the target and visible in the reference). ValueError for a `stride` that is no whole number >= 1."""
    stride = check_whole(stride, "stride")  # 0 divided by zero in np.arange, a negative one compared no pixel
    tps_folder = Path(tps_folder)
    frame = seq.frame(target)
    H, W = frame.shape
    gx, gy = np.meshgrid(np.arange(0, W, stride, dtype=float), np.arange(0, H, stride, dtype=float))
    q = np.stack([gx.ravel(), gy.ravel()], 1)
    exact, visible = seq.correspondences(target, seq.reference, q)
    q, exact = q[visible], exact[visible]
    err = np.linalg.norm(load_authors_spline(tps_folder, target, (W, H))(q) - exact, axis=1)
    ids_r, _, vis_r = seq.landmarks(seq.reference)
    ids_t, xy_t, vis_t = seq.landmarks(target)
    both = vis_t & np.isin(ids_t, ids_r[vis_r])
    inside = inside_hull(xy_t[both], q)
    return MappingErrors(frame=target, inside=err[inside], outside=err[~inside])
