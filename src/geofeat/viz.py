"""Pictures: keypoints with their geodesic support, grids of polar patches, matches."""

from __future__ import annotations

import cv2
import numpy as np

from .frame import RGBDFrame
from .geodesic.mesh import image_to_mesh
from .geodesic.polar import PolarPatches
from .inputs import check_whole


#: BGR colours of `draw_matches`: a correct match under the ground truth, a wrong one, one not judged.
CORRECT, WRONG, UNJUDGED = (0, 200, 0), (0, 0, 255), (255, 120, 0)


def plot_figure(figsize: tuple[float, float]):
    """(fig, ax): a matplotlib Figure of `figsize` inches with one axes, made without pyplot, so no
    backend is chosen or switched (a notebook's or a GUI application's stays as it was) and nothing
    needs closing; `fig.savefig` writes it."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots()


def wrap_text(text: str, font: int, scale: float, room: int) -> list[str]:
    """`text` broken into lines at most `room` pixels wide at `scale` (between words where it can, inside
    a word wider than `room` where it must); one line when it fits, or when `room` holds no character."""
    def width(t: str) -> int:
        return cv2.getTextSize(t, font, scale, 1)[0][0]

    lines: list[str] = []
    line = ""
    for word in text.split(" "):
        candidate = f"{line} {word}" if line else word
        if width(candidate) <= room or not candidate.strip():
            line = candidate
            continue
        if line:
            lines.append(line)
        line = word
        while width(line) > room and len(line) > 1:  # a word wider than the room: cut it where it must
            cut = next((k for k in range(len(line) - 1, 0, -1) if width(line[:k]) <= room), 1)
            lines.append(line[:cut])
            line = line[cut:]
    lines.append(line)
    return lines


#: BGR colour of the box under `put_label`'s text.
LABEL_BOX = (30, 30, 30)


def put_label(canvas: np.ndarray, text: str, origin: tuple[int, int] = (6, 6), scale: float = 0.5,
              colour=(255, 255, 255)) -> tuple[int, int, int, int]:
    """Write `text` on `canvas` (an (H, W, 3) uint8 BGR image, changed in place) in `colour` on a
    filled dark box whose top-left corner is `origin` (x, y pixels), so that it reads on any
    background. Text wider than the canvas right of `origin` is wrapped onto further lines, each on
    its own box below the last (it ran off the picture: a small frame's caption lost its counts).
    The text is drawn once at thickness 1: an outline drawn at a larger thickness does not line up
    with it in every OpenCV version (OpenCV 5 widens its glyphs with the thickness).
    `scale`: OpenCV font scale (0.5 is about 10 px of capital height). Returns the box around all
    its lines (x0, y0, x1, y1)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    pad = max(2, int(round(4 * scale)))
    x0, y0 = int(origin[0]), int(origin[1])
    x1, y = x0, y0
    for line in wrap_text(text, font, scale, canvas.shape[1] - x0 - 2 * pad):
        (w, h), base = cv2.getTextSize(line, font, scale, 1)
        right, bottom = x0 + w + 2 * pad, y + h + base + 2 * pad
        cv2.rectangle(canvas, (x0, y), (right - 1, bottom - 1), LABEL_BOX, -1)
        cv2.putText(canvas, line, (x0 + pad, y + pad + h), font, scale, colour, 1, cv2.LINE_AA)
        x1, y = max(x1, right), bottom
    return x0, y0, x1, y


#: The largest share of a picture's height that `put_caption` lets its caption cover.
CAPTION_MAX_COVER = 0.25


def put_caption(canvas: np.ndarray, lines: list[tuple[str, float]]) -> np.ndarray:
    """`canvas` ((H, W, 3) uint8 BGR) captioned with `lines`, (text, OpenCV font scale) pairs written one
    below the other from its top-left corner (`put_label`, each wrapped to the width). A caption that
    would cover more than `CAPTION_MAX_COVER` of H (a small picture's, its lines wrapped: on 160 x 120
    frames it hid most of them) is written instead into a band of `LABEL_BOX` above the picture, which
    it then hides nothing of. Returns `canvas` written in place, or a new (H + band, W, 3) picture."""
    def write(picture: np.ndarray) -> int:  # the caption's bottom row
        y = 4
        for text, scale in lines:
            y = put_label(picture, text, (4, y), scale)[3]
        return y

    height = write(np.zeros((1, canvas.shape[1], 3), np.uint8))  # measured: only the width wraps the lines
    if height <= CAPTION_MAX_COVER * canvas.shape[0]:
        write(canvas)
        return canvas
    band = np.empty((height + 4, canvas.shape[1], 3), np.uint8)
    band[:] = LABEL_BOX
    write(band)
    return np.concatenate([band, canvas], axis=0)


def to_bgr(frame: RGBDFrame) -> np.ndarray:
    """(H, W, 3) uint8 BGR picture of the frame (its colour image when it has one)."""
    if frame.color is not None:
        return frame.color.copy()
    gray = np.clip(frame.image * 255 + 0.5, 0, 255).astype(np.uint8)
    return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)


#: The widest picture geofeat draws by default, pixels (two 1280-pixel frames side by side): wider
#: ones are shrunk to it (`draw_matches`, `draw_geodesic_support`, the ground truth's overlays), so that
#: a pair of large frames is no 35 MB picture whose 1 px lines and captions vanish when viewed whole.
MAX_PICTURE_WIDTH = 2560
#: `draw_matches`' widest picture by default, pixels (`MAX_PICTURE_WIDTH`).
MAX_MATCHES_WIDTH = MAX_PICTURE_WIDTH


def picture_scale(width: int, max_width: int | None = MAX_PICTURE_WIDTH) -> float:
    """The factor (at most 1) by which a picture `width` pixels wide is shrunk to be at most
    `max_width` pixels wide (None: 1, never shrunk); ValueError for a `max_width` below 2."""
    if max_width is None:
        return 1.0
    check_whole(max_width, "max_width", 2)
    return min(1.0, max_width / width)


def shrink_image(image: np.ndarray, factor: float) -> tuple[np.ndarray, tuple[float, float]]:
    """(image resized by about `factor` (INTER_AREA; meant for < 1), (sx, sy): its new pixels per old pixel)."""
    H, W = image.shape[:2]
    w, h = max(1, int(round(W * factor))), max(1, int(round(H * factor)))
    return cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA), (w / W, h / H)


def shrink_points(xy: np.ndarray, scale: tuple[float, float]) -> np.ndarray:
    """Points (..., 2+) pixels (x, y first) in the picture `shrink_image` made with `scale`: (..., 2)
    (pixel centres kept: `image_to_mesh`). An array of fewer than 2 dimensions is returned as it is."""
    xy = np.asarray(xy, float)
    if xy.ndim < 2:
        return xy
    return image_to_mesh(xy.reshape(-1, xy.shape[-1])[:, :2], scale).reshape(*xy.shape[:-1], 2)


def letterbox(image: np.ndarray, size: tuple[int, int], fill=(255, 255, 255)) -> np.ndarray:
    """`image` ((H, W, 3) uint8) resized by one factor to fit a cell of `size` (w, h) pixels and centred
    in it on `fill` (BGR): its aspect ratio kept, where resizing to `size` squashed it. Returns (h, w, 3) uint8."""
    w, h = size
    H, W = image.shape[:2]
    small, _ = shrink_image(image, min(w / W, h / H))
    small = small[:h, :w]
    cell = np.empty((h, w, 3), np.uint8)
    cell[:] = fill
    y0, x0 = (h - small.shape[0]) // 2, (w - small.shape[1]) // 2
    cell[y0:y0 + small.shape[0], x0:x0 + small.shape[1]] = small
    return cell


def ring_distances_mm(patches: PolarPatches, rings=(7, 15, 31)) -> list[float]:
    """Geodesic distance of each of the patch rows `rings` from its keypoint, millimetres: row i is
    the ring at (i + 1) * radius / n_rings (`geofeat.geodesic.polar`). Rows the patches lack are left out."""
    n_rings = patches.values.shape[1]
    return [(ring + 1) * patches.radius / n_rings * 1000 for ring in rings if ring < n_rings]


def draw_geodesic_support(frame: RGBDFrame, patches: PolarPatches, rings=(7, 15, 31), max_keypoints: int = 64,
                          max_width: int | None = MAX_PICTURE_WIDTH) -> np.ndarray:
    """The frame with each keypoint (white dot), a few of its geodesic rings (isocurves; patch rows
    `rings`) and its angle-0 ray (red), the first `max_keypoints` of them. A key in the top-left corner
    gives each ring's colour and geodesic distance (`ring_distances_mm`), how many of those drawn are
    invalid (drawn as red crosses) and, when keypoints were left out, how many are drawn. Returns an (H, W, 3) uint8 BGR
    image; with no keypoints, the bare frame. A frame wider than `max_width` pixels (None: never) is
    shrunk to it first, the rings and rays with it, as in `draw_matches`."""
    canvas = to_bgr(frame)
    shrink = picture_scale(canvas.shape[1], max_width)
    scale = None  # (sx, sy) of a shrunk frame

    def at(xy: np.ndarray) -> np.ndarray:  # frame pixels -> the picture's
        return xy if scale is None else shrink_points(xy, scale)

    if shrink < 1:
        canvas, scale = shrink_image(canvas, shrink)
    colours = [(255, 200, 0), (0, 200, 255), (0, 255, 0)]
    drawn = [(colour, ring) for colour, ring in zip(colours, rings) if ring < patches.coords.shape[1]]
    for k in range(min(len(patches), max_keypoints)):
        x, y = at(np.asarray(patches.keypoints[k:k + 1], float))[0]
        centre = (int(round(x)), int(round(y)))
        if not patches.valid[k]:
            cv2.drawMarker(canvas, centre, (0, 0, 255), cv2.MARKER_TILTED_CROSS, 10, 2)
            continue
        for colour, ring in drawn:
            pts = np.round(at(patches.coords[k, ring])).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(canvas, [pts], True, colour, 1, cv2.LINE_AA)
        ray = np.round(at(patches.coords[k, :, 0])).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(canvas, [ray], False, (0, 0, 255), 1, cv2.LINE_AA)
        cv2.circle(canvas, centre, 2, (255, 255, 255), -1)
    if len(patches):
        y = 4
        for (colour, ring), mm in zip(drawn, ring_distances_mm(patches, [r for _, r in drawn])):
            y = put_label(canvas, f"ring at {mm:.0f} mm", (4, y), 0.45, colour)[3]
        y = put_label(canvas, "angle-0 ray", (4, y), 0.45, (80, 80, 255))[3]
        # the crosses are red as the rays are: named apart, or they read as rays of a keypoint
        n_invalid = int(np.count_nonzero(~np.asarray(patches.valid[:max_keypoints], bool)))
        if n_invalid:
            y = put_label(canvas, f"red x: {n_invalid} without a patch (invalid)", (4, y), 0.45, (80, 80, 255))[3]
        if len(patches) > max_keypoints:
            put_label(canvas, f"first {max_keypoints} of {len(patches)} keypoints", (4, y), 0.45)
    return canvas


def patch_grid(patches: PolarPatches, columns: int = 8, zoom: int = 3, max_patches: int = 64) -> np.ndarray:
    """Tile polar patches (rows = rings, inner ring on top; columns = angles) into one uint8 BGR
    picture, each labelled with its keypoint index; invalid keypoints get a red tile. Only the first
    `max_patches` are tiled; a last line then says how many of how many."""
    check_whole(columns, "columns", 1)
    check_whole(zoom, "zoom", 1)
    n = min(len(patches), max_patches)
    R, A = patches.values.shape[1:]
    th, tw = R * zoom + 14, A * zoom + 4
    rows = max(1, -(-n // columns))
    note = f"first {n} of {len(patches)} keypoints" if n < len(patches) else ""
    canvas = np.full((rows * th + (20 if note else 0), columns * tw, 3), 255, np.uint8)
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
    if note:
        put_label(canvas, note, (2, rows * th + 1), 0.45)
    return canvas


def side_by_side(left: np.ndarray, right: np.ndarray, gap: int = 8) -> np.ndarray:
    """Place two BGR images next to each other, top-aligned, on white."""
    H = max(left.shape[0], right.shape[0])
    W = left.shape[1] + gap + right.shape[1]
    out = np.full((H, W, 3), 255, np.uint8)
    out[: left.shape[0], : left.shape[1]] = left
    out[: right.shape[0], left.shape[1] + gap:] = right
    return out


def match_key(n_matches: int, n_correct: int, n_drawn: int, judged: bool, n_unjudged: int = 0) -> str:
    """The key under `draw_matches`' title: the colours present ("green: correct, red: wrong", with
    "blue: U not judged (no ground truth)" for the `n_unjudged` of them whose keypoint has none; or
    "blue: not judged (no ground truth)" when none was judged), then "D of N drawn" when only some
    matches are drawn; "no matches" when there is none."""
    if not n_matches:
        return "no matches"
    if judged:
        key = ", ".join(k for k, n in (("green: correct", n_correct), ("red: wrong", n_matches - n_correct - n_unjudged),
                                       (f"blue: {n_unjudged} not judged (no ground truth)", n_unjudged)) if n)
    else:
        key = "blue: not judged (no ground truth)"
    return key + (f"; {n_drawn} of {n_matches} drawn" if n_drawn < n_matches else "")


def draw_matches(
    frame0: RGBDFrame,
    frame1: RGBDFrame,
    keypoints0: np.ndarray,
    keypoints1: np.ndarray,
    matches0: np.ndarray,
    correct: np.ndarray | None = None,
    max_lines: int = 400,
    title: str = "",
    judged: np.ndarray | None = None,
    max_width: int | None = MAX_PICTURE_WIDTH,
) -> np.ndarray:
    """Two frames side by side, frame0 left, with a line per match: green (`CORRECT`) correct, red
    (`WRONG`) wrong, blue (`UNJUDGED`) not judged (correct is None, or `judged` False: no ground
    truth for it, such as an occluded keypoint's; `groundtruth.judged_matches`); correct matches are
    drawn last, over the wrong ones, and those not judged first. keypoints (N, 2) pixels of their own
    frame; matches0 (N0,) int, -1 = none; correct, judged (N0,) bool or None (judged None: every one
    judged). At most `max_lines` matches are drawn (evenly spaced in index order); the caption under
    `title` then says how many of how many, and names the colours used (with the count not judged).
    The keypoints may also be `Keypoints` (as `geofeat.detect` returns them) or cv2.KeyPoints, and
    matches0 a `Matches` record (as `geofeat.match` returns it).
    Returns an (H, W0 + W1, 3) uint8 BGR image, H = max(H0, H1); when W0 + W1 exceeds `max_width`
    pixels (None: never), both frames are shrunk by one factor to fit it, their keypoints with them
    (pixel centres kept: `image_to_mesh`), so that a pair of large frames is no 35 MB picture whose
    1 px lines and caption vanish when it is viewed whole. A caption that would cover more than a
    quarter of H (small frames) is written in a band above the frames instead (`put_caption`), which
    adds the band's rows to H."""
    from .features import Matches
    from .keypoints import as_keypoints

    # `Keypoints` and `Matches`, what detect and match return, were TypeErrors from deep inside
    # ("type Keypoints doesn't define __round__ method", "'>=' not supported ... 'Matches'")
    # (arrays are taken as they were: rows never drawn may hold anything)
    if not isinstance(keypoints0, np.ndarray):
        keypoints0 = as_keypoints(keypoints0, allow_empty=True, what="keypoints0").xy
    if not isinstance(keypoints1, np.ndarray):
        keypoints1 = as_keypoints(keypoints1, allow_empty=True, what="keypoints1").xy
    if isinstance(matches0, Matches):
        matches0 = matches0.matches0
    left, right = to_bgr(frame0), to_bgr(frame1)
    shrink = picture_scale(left.shape[1] + right.shape[1], max_width)
    if shrink < 1:
        left, scale0 = shrink_image(left, shrink)
        right, scale1 = shrink_image(right, shrink)
        keypoints0, keypoints1 = shrink_points(keypoints0, scale0), shrink_points(keypoints1, scale1)
    canvas = side_by_side(left, right, gap=0)
    offset = left.shape[1]
    matches0 = np.asarray(matches0)
    i0 = np.flatnonzero(matches0 >= 0)
    total = len(i0)
    if total > max_lines:
        i0 = i0[np.linspace(0, total - 1, max_lines).astype(int)]
    unjudged = np.zeros(len(matches0), bool)
    if correct is not None:
        correct = np.asarray(correct, bool)
        if judged is not None:
            unjudged = ~np.asarray(judged, bool) & ~correct
        # those not judged under the wrong ones, the correct ones over both: the correct ones stay visible
        i0 = np.concatenate([i0[unjudged[i0]], i0[~correct[i0] & ~unjudged[i0]], i0[correct[i0]]])
    for i in i0:
        j = matches0[i]
        colour = UNJUDGED if correct is None or unjudged[i] else (CORRECT if correct[i] else WRONG)
        p = (int(round(keypoints0[i][0])), int(round(keypoints0[i][1])))
        q = (int(round(keypoints1[j][0])) + offset, int(round(keypoints1[j][1])))
        cv2.line(canvas, p, q, colour, 1, cv2.LINE_AA)
        cv2.circle(canvas, p, 2, colour, -1)
        cv2.circle(canvas, q, 2, colour, -1)
    n_ok = 0 if correct is None else int(correct[matches0 >= 0].sum())
    key = match_key(total, n_ok, len(i0), correct is not None, int(unjudged[matches0 >= 0].sum()))
    lines = [t for t in (title, key) if t]
    return put_caption(canvas, [(line, 0.55 if k == 0 else 0.45) for k, line in enumerate(lines)])
