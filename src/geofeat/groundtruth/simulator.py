"""Exact dense ground truth of simulated sequences (written by `geofeat.sim`, read by `geofeat.io`):
pixel correspondences between any two frames.

Per frame the simulator stores `<name>-gt.npz`:
    uv        (H, W, 2) float32 surface coordinate (u, v) of the cloth seen at each pixel centre,
              metres on the flat rest cloth; -1 on background,
    vertices  (rows, cols, 3) float64 particle positions in that frame's camera coordinates, metres,
    R, t      (3, 3), (3,) the world-to-camera pose (world = the reference camera),
and one `groundtruth.json` per sequence (grid shape, particle spacing, frame names).

Pixels are in the OpenCV convention: the centre of the top-left pixel is (0, 0).
Because the cloth is isometric (up to the constraint tolerance), the geodesic distance between
two surface points is the Euclidean distance of their (u, v).

Mapping a point p of frame i to frame j:
 1. the (u, v) of p: where the ray through p meets the cloth (exact sub-pixel surface coordinate),
    found by walking from the triangle seen at the nearest pixel centre to the triangle the ray
    hits; p is off-surface if that pixel is background;
 2. (u, v) -> 3D point on the same triangle of the piecewise-linear surface in frame j -> pinhole
    projection;
 3. visible in j if the projection lands in the image, in front of the camera, and the surface
    seen at the nearest pixel centre there is the same point: |uv_j(pixel) - (u, v)| below
    `tol_px` pixel footprints (divided by the cosine of the viewing angle) and not in front of it
    (depth within the point's own slope over 0.75 px), no part of the cloth lies in front of it on its
    own ray (searched from the triangles seen at the four pixel centres around it), and frame j sees the
    front side of the cloth there (the side the reference camera sees). Points hidden by a fold
    (another part of the cloth, far away in (u, v)), seen from the back, or off the image are not
    visible.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..inputs import as_points

GT_JSON = "groundtruth.json"
GT_SUFFIX = "-gt.npz"
#: Visibility tolerance in pixel footprints (see the module docstring).
VISIBILITY_TOL_PX = 2.0


@dataclass
class FrameTruth:
    """Ground truth of one frame: uv (H, W, 2) float32 metres (-1 = background) and
    vertices (rows, cols, 3) float64 camera coordinates, metres."""

    uv: np.ndarray
    vertices: np.ndarray


def _triangles_of(uv: np.ndarray, rows: int, cols: int, spacing: float):
    """Grid triangle of surface coordinates uv (N, 2) metres: cell (r, c), fractional (fu, fv) and
    `upper` (fu >= fv: triangle (r,c),(r,c+1),(r+1,c+1); else (r,c),(r+1,c+1),(r+1,c))."""
    cu = uv[:, 0] / spacing
    cv = uv[:, 1] / spacing
    c = np.clip(np.floor(cu), 0, cols - 2).astype(np.int64)
    r = np.clip(np.floor(cv), 0, rows - 2).astype(np.int64)
    fu = cu - c
    fv = cv - r
    return r, c, fu, fv, fu >= fv


def _triangle_vertices(vertices: np.ndarray, r, c, upper):
    """(N, 3) x 3 vertex positions A, B, C of the triangles, ordered so that the point with
    fractional cell position (fu, fv) is A + s (B - A) + q (C - B), (s, q) = (fu, fv) if upper else (fv, fu)."""
    v00 = vertices[r, c]
    v11 = vertices[r + 1, c + 1]
    other = np.where(upper[:, None], vertices[r, c + 1], vertices[r + 1, c])
    return v00, other, v11


def surface_to_points(uv: np.ndarray, vertices: np.ndarray, spacing: float) -> np.ndarray:
    """3D positions (N, 3) metres of surface coordinates uv (N, 2) metres on the piecewise-linear
    cloth with grid `vertices` (rows, cols, 3)."""
    rows, cols = vertices.shape[:2]
    r, c, fu, fv, upper = _triangles_of(uv, rows, cols, spacing)
    a, b, cc = _triangle_vertices(vertices, r, c, upper)
    s = np.where(upper, fu, fv)[:, None]
    q = np.where(upper, fv, fu)[:, None]
    return a + s * (b - a) + q * (cc - b)


def _pixel_lookup(uv_map: np.ndarray, points: np.ndarray):
    H, W = uv_map.shape[:2]
    px = np.rint(points[:, 0]).astype(np.int64)
    py = np.rint(points[:, 1]).astype(np.int64)
    inside = (px >= 0) & (px < W) & (py >= 0) & (py < H) & np.isfinite(points).all(axis=1)
    uv = np.full((len(points), 2), -1.0)
    uv[inside] = uv_map[py[inside], px[inside]]
    return uv, inside & (uv[:, 0] >= 0)


#: Triangles visited at most when walking from the triangle seen at the nearest pixel centre to the
#: one the ray through a sub-pixel point hits (`surface_coordinates`).
MAX_WALK = 8


def _ray_in_triangle(vertices: np.ndarray, ray: np.ndarray, r, c, upper):
    """Intersect rays (N, 3) through the camera centre with the planes of grid triangles (r, c, upper).

    Returns:
        fu, fv (N,) the intersection's fractional position in cell (r, c) (outside [0, 1] or on the
        wrong side of the diagonal when the ray misses the triangle), good (N,) bool: the ray is not
        parallel to the plane and the triangle is not degenerate.
    """
    a, b, cc = _triangle_vertices(vertices, r, c, upper)
    e1, e2 = b - a, cc - b
    n = np.cross(e1, e2)
    denom = np.einsum("ij,ij->i", n, ray)
    good = np.abs(denom) > 1e-12 * np.linalg.norm(n, axis=1)
    lam = np.einsum("ij,ij->i", n, a) / np.where(good, denom, 1.0)
    p = ray * lam[:, None] - a
    # solve p = s e1 + q e2 in the least-squares sense (p lies in the plane)
    g11 = np.einsum("ij,ij->i", e1, e1)
    g12 = np.einsum("ij,ij->i", e1, e2)
    g22 = np.einsum("ij,ij->i", e2, e2)
    h1 = np.einsum("ij,ij->i", e1, p)
    h2 = np.einsum("ij,ij->i", e2, p)
    det = g11 * g22 - g12 * g12
    good &= det > 1e-30
    det = np.where(good, det, 1.0)
    s = (g22 * h1 - g12 * h2) / det
    q = (g11 * h2 - g12 * h1) / det
    return np.where(upper, s, q), np.where(upper, q, s), good


def surface_coordinates(truth: FrameTruth, K: np.ndarray, spacing: float, points: np.ndarray):
    """Exact (u, v) in metres of sub-pixel points (N, 2) of a frame: where the ray through the point
    meets the rendered (piecewise-flat) cloth.

    The triangle seen at the nearest pixel centre is a start: when the ray meets its plane outside
    it (the point lies over a neighbouring triangle, common where triangles are a few pixels wide),
    the search walks to the triangle holding that intersection, up to `MAX_WALK` triangles.

    Returns:
        uv (N, 2) float64 metres (-1 where off-surface), on_surface (N,) bool.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    uv, ok = _pixel_lookup(truth.uv, points)
    if not ok.any():
        return uv, ok
    uv[ok] = _walk(truth, K, spacing, points[ok], uv[ok])
    return uv, ok


def _walk(truth: FrameTruth, K: np.ndarray, spacing: float, points: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """(N, 2) (u, v) where the rays through `points` (N, 2) meet the cloth, walking from the triangles
    of `seed` (N, 2) (see `surface_coordinates`)."""
    rows, cols = truth.vertices.shape[:2]
    ray = np.stack([(points[:, 0] - K[0, 2]) / K[0, 0], (points[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(points))], axis=1)
    result = seed.copy()
    current, todo = seed.copy(), np.arange(len(seed))
    extent = np.array([cols - 1, rows - 1]) * spacing
    for step in range(MAX_WALK):
        r, c, _, _, upper = _triangles_of(current[todo], rows, cols, spacing)
        fu, fv, good = _ray_in_triangle(truth.vertices, ray[todo], r, c, upper)
        hit = np.stack([(c + fu) * spacing, (r + fv) * spacing], axis=1)
        if step == 0:
            # fallback where no visited triangle holds the intersection (the ray passes a silhouette or
            # the cloth border): the intersection with the seed triangle's plane, or the pixel-centre
            # value where that jumps (it is then an extrapolation far off the triangle)
            near = good & (np.linalg.norm(hit - seed, axis=1) <= 2 * spacing)
            result[near] = hit[near]
        # inside the triangle: 0 <= fv <= fu <= 1 (upper) or 0 <= fu <= fv <= 1 (lower), with slack
        lo, hi = np.where(upper, fv, fu), np.where(upper, fu, fv)
        inside = good & (lo >= -1e-9) & (hi <= 1 + 1e-9) & (np.where(upper, fu - fv, fv - fu) >= -1e-9)
        result[todo[inside]] = hit[inside]
        # walk on to the triangle holding the intersection, unless it is off the cloth
        go = ~inside & good & (hit >= 0).all(axis=1) & (hit <= extent).all(axis=1)
        todo = todo[go]
        current[todo] = hit[go]
        if not len(todo):
            break
    return result


def map_points(
    truth_i: FrameTruth,
    truth_j: FrameTruth,
    K: np.ndarray,
    spacing: float,
    points: np.ndarray,
    tol_px: float = VISIBILITY_TOL_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """Map sub-pixel points (N, 2) of frame i to frame j (see the module docstring).

    Returns:
        mapped (N, 2) float64 pixels of frame j (NaN where the point is off the surface in frame i;
        the projection, possibly outside the image, where it is on the surface but hidden),
        visible (N,) bool.
    """
    K = np.asarray(K, dtype=np.float64)
    uv, on = surface_coordinates(truth_i, K, spacing, points)
    mapped = np.full((len(uv), 2), np.nan)
    visible = np.zeros(len(uv), dtype=bool)
    if not on.any():
        return mapped, visible
    P = surface_to_points(uv[on], truth_j.vertices, spacing)
    Z = P[:, 2]
    front = Z > 1e-6
    Zs = np.where(front, Z, 1.0)
    proj = np.stack([K[0, 0] * P[:, 0] / Zs + K[0, 2], K[1, 1] * P[:, 1] / Zs + K[1, 2]], axis=1)
    proj[~front] = np.nan
    mapped[on] = proj
    uv_j, ok_j = _pixel_lookup(truth_j.uv, np.where(front[:, None], proj, -1e9))
    # pixel footprint (metres) divided by the cosine between normal and viewing ray
    rows, cols = truth_j.vertices.shape[:2]
    r, c, _, _, upper = _triangles_of(uv[on], rows, cols, spacing)
    a, b, cc = _triangle_vertices(truth_j.vertices, r, c, upper)
    n = np.cross(b - a, cc - b)
    # front side seen: du x dv (upper triangles; dv x du for the lower ones) points away from the camera
    facing = np.where(upper, 1.0, -1.0) * np.einsum("ij,ij->i", n, P) > 0
    cos = np.abs(np.einsum("ij,ij->i", n, P)) / (np.linalg.norm(n, axis=1) * np.linalg.norm(P, axis=1) + 1e-30)
    footprint = Zs / min(K[0, 0], K[1, 1])
    tol = tol_px * footprint / np.maximum(cos, 0.2)
    same = np.linalg.norm(uv_j - uv[on], axis=1) <= tol
    # and nothing in front: the surface seen at that pixel centre is not closer than the point by more
    # than the depth change of the point's own surface over 0.75 px (a tight fold can bring a layer
    # whose (u, v) is close to the point's in front of it)
    seen_z = surface_to_points(np.where(ok_j[:, None], uv_j, 0.0), truth_j.vertices, spacing)[:, 2]
    slope = np.sqrt(np.maximum(1.0 - cos**2, 0.0)) / np.maximum(cos, 0.2)
    unoccluded = seen_z >= Zs - (0.75 * footprint * slope + 0.5 * footprint)
    # and nothing in front on the ray itself. The tests above look at the nearest pixel centre only and
    # allow for the slope of the point's own surface (up to 10 footprints of (u, v) at grazing angles), which
    # let points hidden by a fold up to 15 cm in front pass as visible (4 % of the visible points of a
    # `hard` frame): where the ray through the projection meets the cloth is searched from the triangles
    # seen at the four pixel centres around it, and a hit in front of the point hides it
    vis = np.flatnonzero(front & ok_j & same & facing & unoccluded)
    extent = np.array([cols - 1, rows - 1]) * spacing
    H, W = truth_j.uv.shape[:2]
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        if not len(vis):
            break
        corner = np.floor(proj[vis]) + [dx, dy]
        seed, seen = _pixel_lookup(truth_j.uv, np.minimum(corner, [W - 1, H - 1]))
        if not seen.any():
            continue
        at = vis[seen]
        uv_hit = _walk(truth_j, K, spacing, proj[at], seed[seen])
        Q = surface_to_points(uv_hit, truth_j.vertices, spacing)
        Qz = np.where(Q[:, 2] > 1e-6, Q[:, 2], 1.0)
        on_ray = np.hypot(K[0, 0] * Q[:, 0] / Qz + K[0, 2] - proj[at, 0],
                          K[1, 1] * Q[:, 1] / Qz + K[1, 2] - proj[at, 1]) < 0.01
        on_cloth = (uv_hit >= 0).all(axis=1) & (uv_hit <= extent).all(axis=1)
        hidden = on_ray & on_cloth & (Q[:, 2] > 1e-6) & (Q[:, 2] < Zs[at] - 0.05 * footprint[at])
        unoccluded[at[hidden]] = False
        vis = vis[unoccluded[vis]]
    visible[on] = front & ok_j & same & facing & unoccluded
    return mapped, visible


# --------------------------------------------------------------------------- on-disk sequences


def missing_ground_truth(seq) -> list[str]:
    """The simulator's ground-truth files that the `geofeat.io.Sequence` lacks: `groundtruth.json` and
    each frame's `<frame>-gt.npz`; [] when its dense ground truth is whole."""
    folder = Path(seq.folder)
    return ([] if (folder / GT_JSON).is_file() else [GT_JSON]) + \
        [f"{n}{GT_SUFFIX}" for n in seq.names if not (folder / f"{n}{GT_SUFFIX}").is_file()]


def has_ground_truth(seq) -> bool:
    """True if the `geofeat.io.Sequence` was written by the simulator with its dense ground truth."""
    return not missing_ground_truth(seq)


def read_metadata(folder: str | Path) -> dict:
    """The sequence's `groundtruth.json` as a dict (ValueError naming the file when it is not a JSON
    object: a corrupt file was a bare JSON error, a list a TypeError traceback)."""
    path = Path(folder) / GT_JSON
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(meta).__name__}")
    return meta


def read_frame_truth(folder: str | Path, name: str | int) -> FrameTruth:
    """Load `<name>-gt.npz` of a simulated sequence (name, or index into its frame list)."""
    if isinstance(name, (int, np.integer)):
        name = read_metadata(folder)["frames"][int(name)]
    path = Path(folder) / f"{name}{GT_SUFFIX}"
    try:  # a truncated or foreign file was a BadZipFile / KeyError traceback in `geofeat match`
        with np.load(path) as data:
            return FrameTruth(uv=data["uv"], vertices=data["vertices"])
    except (ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as error:
        raise ValueError(f"{path}: not a ground-truth file of `geofeat simulate` (arrays uv and vertices): "
                         f"{type(error).__name__}: {error}") from None


def _check_truth_size(seq, name: str, truth: FrameTruth) -> None:
    """ValueError when frame `name`'s uv map is not of the sequence's (H, W) image size (`seq.shape`,
    unchecked when None): frames resized or cropped after simulation, their `<frame>-gt.npz` kept. The
    uv map is read at the frame's pixels, so every point was looked up at another place of the cloth
    and no pair was found visible, without a word."""
    shape = getattr(seq, "shape", None)
    if shape is not None and truth.uv.shape[:2] != tuple(shape):
        h, w = truth.uv.shape[:2]
        raise ValueError(f"{Path(seq.folder) / f'{name}{GT_SUFFIX}'}: the simulator's ground truth is {w}x{h}, the "
                         f"frames of {seq.folder} {shape[1]}x{shape[0]} (resized or cropped after `geofeat simulate`?); "
                         f"it maps pixels of the size it was simulated at: simulate the sequence again at this size, "
                         f"or remove every <frame>{GT_SUFFIX} to score it with its csv landmarks")


def correspondences(seq, i, j, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map pixels of frame i to frame j of a simulated `geofeat.io.Sequence`.

    Args:
        seq: the sequence (from `geofeat.read_sequence`).
        i, j: frame names or indices into `seq.names`.
        points: (N, 2) pixel coordinates (x, y) of frame i, OpenCV convention.

    Returns:
        mapped (N, 2) float64 pixels of frame j (NaN where the point is off the cloth in frame i),
        visible (N,) bool: on the cloth in frame i and seen, not occluded, inside frame j.
    """
    if not has_ground_truth(seq):
        raise ValueError(
            f"sequence {seq.folder} has no simulator ground truth ({GT_JSON} and <name>{GT_SUFFIX} files); "
            "only sequences written by `geofeat simulate` have dense correspondences"
        )
    points = as_points(points, "points")
    meta = read_metadata(seq.folder)
    ti = read_frame_truth(seq.folder, seq.frame_name(i))
    tj = read_frame_truth(seq.folder, seq.frame_name(j))
    for name, truth in ((seq.frame_name(i), ti), (seq.frame_name(j), tj)):
        _check_truth_size(seq, name, truth)
    try:
        spacing = float(meta["spacing_m"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{Path(seq.folder) / GT_JSON}: expected a number 'spacing_m' (the cloth's grid spacing, "
                         f"metres), got {meta.get('spacing_m')!r}") from None
    return map_points(ti, tj, seq.K, spacing, points)
