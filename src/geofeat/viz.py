"""Pictures: keypoints with their geodesic support, grids of polar patches, matches."""

from __future__ import annotations

import cv2
import numpy as np

from .frame import RGBDFrame
from .geodesic.polar import PolarPatches
from .inputs import check_whole


def to_bgr(frame: RGBDFrame) -> np.ndarray:
    """(H, W, 3) uint8 BGR picture of the frame (its colour image when it has one)."""
    if frame.color is not None:
        return frame.color.copy()
    gray = np.clip(frame.image * 255 + 0.5, 0, 255).astype(np.uint8)
    return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)


def draw_geodesic_support(frame: RGBDFrame, patches: PolarPatches, rings=(7, 15, 31), max_keypoints: int = 64) -> np.ndarray:
    """The frame with each keypoint, a few of its geodesic rings (isocurves) and its angle-0 ray.

    Invalid keypoints are drawn as red crosses. Returns an (H, W, 3) uint8 BGR image."""
    canvas = to_bgr(frame)
    colours = [(255, 200, 0), (0, 200, 255), (0, 255, 0)]
    for k in range(min(len(patches), max_keypoints)):
        x, y = patches.keypoints[k]
        centre = (int(round(x)), int(round(y)))
        if not patches.valid[k]:
            cv2.drawMarker(canvas, centre, (0, 0, 255), cv2.MARKER_TILTED_CROSS, 10, 2)
            continue
        for colour, ring in zip(colours, rings):
            if ring >= patches.coords.shape[1]:
                continue
            pts = np.round(patches.coords[k, ring]).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(canvas, [pts], True, colour, 1, cv2.LINE_AA)
        ray = np.round(patches.coords[k, :, 0]).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(canvas, [ray], False, (0, 0, 255), 1, cv2.LINE_AA)
        cv2.circle(canvas, centre, 2, (255, 255, 255), -1)
    return canvas


def patch_grid(patches: PolarPatches, columns: int = 8, zoom: int = 3, max_patches: int = 64) -> np.ndarray:
    """Tile polar patches (rows = rings, columns = angles) into one uint8 BGR picture, each labelled
    with its keypoint index; invalid keypoints get a red tile."""
    check_whole(columns, "columns", 1)
    check_whole(zoom, "zoom", 1)
    n = min(len(patches), max_patches)
    R, A = patches.values.shape[1:]
    th, tw = R * zoom + 14, A * zoom + 4
    rows = max(1, -(-n // columns))
    canvas = np.full((rows * th, columns * tw, 3), 255, np.uint8)
    for k in range(n):
        r, c = divmod(k, columns)
        tile = np.clip(patches.values[k] * 255 + 0.5, 0, 255).astype(np.uint8)
        tile = cv2.resize(tile, (A * zoom, R * zoom), interpolation=cv2.INTER_NEAREST)
        tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR)
        if not patches.valid[k]:
            tile[:] = (60, 60, 200)
        y0, x0 = r * th + 12, c * tw + 2
        canvas[y0:y0 + R * zoom, x0:x0 + A * zoom] = tile
        cv2.putText(canvas, str(k), (x0, y0 - 2), cv2.FONT_HERSHEY_PLAIN, 0.8, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas


def side_by_side(left: np.ndarray, right: np.ndarray, gap: int = 8) -> np.ndarray:
    """Place two BGR images next to each other, top-aligned, on white."""
    H = max(left.shape[0], right.shape[0])
    W = left.shape[1] + gap + right.shape[1]
    out = np.full((H, W, 3), 255, np.uint8)
    out[: left.shape[0], : left.shape[1]] = left
    out[: right.shape[0], left.shape[1] + gap:] = right
    return out


def draw_matches(
    frame0: RGBDFrame,
    frame1: RGBDFrame,
    keypoints0: np.ndarray,
    keypoints1: np.ndarray,
    matches0: np.ndarray,
    correct: np.ndarray | None = None,
    max_lines: int = 400,
    title: str = "",
) -> np.ndarray:
    """Two frames side by side with a line per match: green correct, red wrong, blue unknown
    (correct is None). keypoints (N, 2) pixels; matches0 (N0,) int, -1 = none. Returns uint8 BGR."""
    left, right = to_bgr(frame0), to_bgr(frame1)
    canvas = side_by_side(left, right, gap=0)
    offset = left.shape[1]
    i0 = np.flatnonzero(np.asarray(matches0) >= 0)
    if len(i0) > max_lines:
        i0 = i0[np.linspace(0, len(i0) - 1, max_lines).astype(int)]
    for i in i0:
        j = matches0[i]
        colour = (255, 120, 0) if correct is None else ((0, 200, 0) if correct[i] else (0, 0, 255))
        p = (int(round(keypoints0[i][0])), int(round(keypoints0[i][1])))
        q = (int(round(keypoints1[j][0])) + offset, int(round(keypoints1[j][1])))
        cv2.line(canvas, p, q, colour, 1, cv2.LINE_AA)
        cv2.circle(canvas, p, 2, colour, -1)
        cv2.circle(canvas, q, 2, colour, -1)
    if title:
        cv2.putText(canvas, title, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(canvas, title, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas
