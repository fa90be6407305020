"""The object's pixels in a frame, for the applications (retrieval, tracking).

Sources, in this order:
- "simulator": the simulator's ground truth (`<name>-gt.npz`, cloth where uv >= 0);
- "objmask": the authors' TPS ground truth (`<tps_dir>/<sequence>/<name>_objmask.png`);
- "depth": the foreground surface found from depth (see `foreground_from_depth`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..io import Sequence

__all__ = ["object_mask", "foreground_from_depth", "MASK_SOURCES"]

MASK_SOURCES = ("simulator", "objmask", "depth")

#: Depth gap (metres) between the near and far Otsu classes above which the far class is background.
BACKGROUND_GAP_M = 0.15


def foreground_from_depth(depth: np.ndarray, gap_m: float = BACKGROUND_GAP_M) -> np.ndarray:
    """(H, W) bool foreground of a depth map (H, W) in metres (0 = missing).

    Valid depths are split in two by Otsu's threshold; when the mean depths of the two classes differ
    by more than `gap_m` metres, the far class is background. The largest connected component of
    what is left (holes closed) is the object.
    """
    depth = np.asarray(depth, np.float32)
    valid = depth > 0
    if valid.sum() < 16:
        raise ValueError("depth: fewer than 16 pixels with depth; cannot find a foreground object")
    d = depth[valid]
    lo, hi = float(d.min()), float(d.max())
    fg = valid.copy()
    if hi - lo > gap_m:
        scaled = np.zeros(depth.shape, np.uint8)
        scaled[valid] = np.clip((depth[valid] - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)
        t, _ = cv2.threshold(scaled[valid].reshape(-1, 1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        threshold = lo + (t + 0.5) / 255.0 * (hi - lo)
        near, far = d[d <= threshold], d[d > threshold]
        if len(near) and len(far) and far.mean() - near.mean() > gap_m:
            fg = valid & (depth <= threshold)
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        return fg > 0
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == largest


def object_mask(seq: Sequence, name: str, tps_dir: str | Path | None = None) -> tuple[np.ndarray, str]:
    """The object mask of frame `name` of `seq` and its source.

    Returns:
        mask (H, W) bool, and the source: "simulator", "objmask" or "depth" (see module docstring).
    """
    from ..groundtruth.simulator import GT_SUFFIX

    gt = seq.folder / f"{name}{GT_SUFFIX}"
    if gt.is_file():
        with np.load(gt) as data:
            return data["uv"][..., 0] >= 0, "simulator"
    if tps_dir is not None:
        from ..groundtruth.sources import tps_folder

        folder = tps_folder(str(tps_dir), seq.name)
        path = None if folder is None else folder / f"{name}_objmask.png"
        if path is not None and path.is_file():
            # unchanged, not IMREAD_GRAYSCALE: that reads a 16-bit 0/1 or 0/255 mask as all zeros
            m = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # (as stored: UNCHANGED ignores an EXIF orientation)
            if m is None:
                raise ValueError(f"tps-dir: cannot read {path}")
            if m.ndim == 3:  # colour: object where any colour channel (not the alpha) is non-zero
                m = m[..., :3].max(axis=2)
            shape = seq.shape if seq.shape is not None else seq.frame(name).shape
            if m.shape != tuple(shape):  # a mask of another size put the ROI in the wrong pixels
                raise ValueError(f"tps-dir: {path} is {m.shape[1]}x{m.shape[0]}, the frames of {seq.name} are "
                                 f"{shape[1]}x{shape[0]}")
            return m > 0, "objmask"
    return foreground_from_depth(seq.frame(name).depth), "depth"
