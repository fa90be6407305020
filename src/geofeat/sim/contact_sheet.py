"""Contact sheet: a few frames of a simulated sequence with ground-truth tracks drawn."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..io import read_sequence
from ..groundtruth.simulator import correspondences
from ..outputs import write_picture
from ..viz import put_label


def contact_sheet(folder: str | Path, out_png: str | Path, n_frames: int = 6, n_tracks: int = 16,
                  tile_width: int = 320, seed: int = 0) -> np.ndarray:
    """Write a PNG of `n_frames` evenly spaced frames (two rows) with `n_tracks` random reference
    pixels mapped by the exact ground truth (filled dot: visible; hollow: occluded / off-frame; the
    first tile says so).
    Returns the (H, W, 3) uint8 BGR sheet."""
    seq = read_sequence(folder)
    idx = np.unique(np.linspace(0, len(seq) - 1, min(n_frames, len(seq))).round().astype(int))
    ref = seq.frame(0)
    ys, xs = np.nonzero(ref.depth > 0)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(xs), size=min(n_tracks, len(xs)), replace=False) if len(xs) else np.zeros(0, int)
    pts = np.stack([xs[pick], ys[pick]], axis=1).astype(np.float64)
    colors = [tuple(int(c) for c in cv2.cvtColor(np.uint8([[[int(180 * k / max(len(pts), 1)), 255, 255]]]),
                                                  cv2.COLOR_HSV2BGR)[0, 0]) for k in range(len(pts))]
    H, W = ref.shape
    scale = tile_width / W
    tiles = []
    for i in idx:
        image = cv2.imread(str(seq.folder / f"{seq.names[i]}-rgb.png"))
        mapped, visible = correspondences(seq, 0, int(i), pts)
        tile = cv2.resize(image, (tile_width, int(round(H * scale))), interpolation=cv2.INTER_AREA)
        for (x, y), v, col in zip(mapped, visible, colors):
            if not np.isfinite(x):
                continue
            c = (int(round((x + 0.5) * scale - 0.5)), int(round((y + 0.5) * scale - 0.5)))
            cv2.circle(tile, c, 4, col, -1 if v else 1, cv2.LINE_AA)
        y = put_label(tile, seq.names[i], (4, 4), 0.45)[3]
        if not tiles:  # the key, once: the sheet was the dots alone, filled or hollow, and no word of what they mean
            put_label(tile, "dots: true tracks; hollow: hidden or off frame", (4, y), 0.4)
        tiles.append(tile)
    while len(tiles) % 2 and len(tiles) > 1:
        tiles.append(np.zeros_like(tiles[0]))
    half = max(1, len(tiles) // 2) if len(tiles) > 1 else 1
    rows = [np.concatenate(tiles[k : k + half], axis=1) for k in range(0, len(tiles), half)]
    sheet = np.concatenate(rows, axis=0)
    write_picture(out_png, sheet)  # whole or not at all
    return sheet
