"""Geodesic polar patches: the mapping f(.) of the paper.

For every keypoint, `n_angles` straightest geodesics leave the keypoint on the depth surface and are
sampled every radius / n_rings of arc length; the samples are projected into the image and the gray
image is read there (bilinear). Row i of a patch is the ring at geodesic distance
(i + 1) * radius / n_rings; column k is the direction at angle 2 pi k / n_angles, counter-clockwise as
displayed, from the image +x axis projected onto the surface's tangent plane at the keypoint.
"""

from __future__ import annotations

import numbers
import zlib
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..constants import DEFAULT_RADIUS_M, N_ANGLES, N_RINGS, SAMPLING_BLUR_PX
from ..depth import DepthConfig, depth_config_name
from ..frame import RGBDFrame
from ..inputs import check_radius, check_whole
from ..keypoints import as_keypoints
from .mesh import GridMesh, frame_depth_config, frame_fingerprint, frame_mesh
from .walk import MAX_CROSSINGS, walk_polar


@dataclass
class PolarPatches:
    """Polar patches of N keypoints.

    Attributes:
        keypoints: (N, 2) float64 image pixel coordinates (x, y).
        values: (N, R, A) float32 gray intensities in [0, 1]; 0 for invalid keypoints.
        coords: (N, R, A, 2) float32 image pixel coordinates (x, y) of every sample; NaN for invalid
            keypoints.
        valid: (N,) bool. False when the keypoint has no surface under it (missing depth, mesh border,
            depth discontinuity) or when fewer than half of the directions reach the first ring (see
            `patch_validity`).
        rings_reached: (N, A) int32, rings of each direction that lie on the surface. A ray that
            leaves the surface early (hole, border, discontinuity) repeats the last surface point it
            reached in its remaining rings, so every sample lies on the mesh.
        points: (N, R, A, 3) float32 camera-frame 3D positions of the samples, metres.
        radius: geodesic radius of the outer ring, metres.
        source: `patch_source` of the frame they were computed on (its depth, intrinsics and gray
            image), None when unknown; a descriptor given them with another frame refuses them.
        blur_px: the Gaussian blur of the image they were sampled from, pixels (`sampling_image`).
        depth_config: the `DepthConfig` of the mesh their rays walked on (a profile name resolved on
            the frame: "auto" is the profile it picked).
            A descriptor given patches of another blur or depth config than its own refuses them
            (`check_patches`); None (unknown, e.g. patches made by hand or walked on a mesh of
            `mesh_from_points`) is not checked.
    """

    keypoints: np.ndarray
    values: np.ndarray
    coords: np.ndarray
    valid: np.ndarray
    rings_reached: np.ndarray
    points: np.ndarray
    radius: float
    source: tuple | None = field(default=None, repr=False, compare=False)
    blur_px: float | None = field(default=None, repr=False, compare=False)
    depth_config: DepthConfig | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.keypoints)

    def __repr__(self) -> str:  # the dataclass's printed every array in full
        return (f"PolarPatches({len(self)} keypoints, {int(np.asarray(self.valid).sum())} valid, "
                f"{self.values.shape[1]} rings x {self.values.shape[2]} angles, radius {self.radius:g} m)")


def as_keypoint_array(keypoints, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(N, 2) float64 pixel coordinates of keypoints given in any form `geofeat.keypoints.as_keypoints`
    accepts ((N, 2) array, cv2.KeyPoint list, `Keypoints`); off-image or empty sets raise ValueError."""
    return as_keypoints(keypoints, shape).xy


def check_patch_request(frame: RGBDFrame, keypoints, radius: float, n_angles: int, n_rings: int) -> np.ndarray:
    """Validate the arguments shared by the polar patch builders; returns the (N, 2) keypoints."""
    if not isinstance(frame, RGBDFrame):
        raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
    check_radius(radius, "radius")  # metres, within inputs.PLAUSIBLE_RADIUS_M, as for the commands
    check_whole(n_angles, "n_angles", 1)
    check_whole(n_rings, "n_rings", 1)
    return as_keypoint_array(keypoints, frame.shape)


def patch_source(frame: RGBDFrame, fingerprint: tuple | None = None) -> tuple:
    """What a frame's polar patches depend on (`PolarPatches.source`): its `frame_fingerprint` (depth
    and intrinsics, where the walk goes; `fingerprint` when already computed) and a CRC-32 of its gray
    image (what is read there). The fingerprint alone let the patches of a frame describe another
    frame of the same depth and intrinsics, e.g. `frame.with_image(filtered)`, with the first
    frame's intensities."""
    fingerprint = fingerprint if fingerprint is not None else frame_fingerprint(frame)
    return fingerprint + (zlib.crc32(np.ascontiguousarray(frame.image)),)


def check_depth_config(recorded: DepthConfig | None, depth_config, frame: RGBDFrame, what: str,
                       fingerprint: tuple | None = None) -> None:
    """A mesh, or patches walked on one (`what` names them), made with the DepthConfig `recorded` must
    be made with the descriptor's `depth_config` (a DepthConfig or a profile name, resolved on
    `frame`: "auto" is the profile it picks there, so patches of that profile pass); ValueError naming
    both otherwise. Unknown (None) on either side passes. `fingerprint`: the frame's
    `frame_fingerprint`, when the caller has computed it."""
    if recorded is None or depth_config is None:
        return
    wanted = frame_depth_config(frame, depth_config, fingerprint)
    if wanted == recorded:
        return
    given = repr(depth_config) if isinstance(depth_config, str) else depth_config_name(depth_config)
    on_frame = f" ({depth_config_name(wanted)} on this frame)" if depth_config == "auto" else ""
    made = "built" if what == "mesh" else "walked on a mesh built"
    raise ValueError(f"{what}: {made} with depth config {depth_config_name(recorded)}, but the descriptor's "
                     f"depth_config is {given}{on_frame}; build them with the descriptor's depth_config, or the "
                     f"descriptor with depth_config={depth_config_name(recorded)}")


def check_patches(patches, xy: np.ndarray, radius: float | None = None, frame: RGBDFrame | None = None,
                  blur_px: float | None = None, depth_config=None) -> PolarPatches:
    """Precomputed patches given to a descriptor with its (N, 2) keypoints `xy` must be the
    `PolarPatches` of those keypoints, in that order, of the descriptor's geodesic `radius`
    (metres; None: any), of `frame` (None: any; patches whose `source` is unknown pass), sampled
    with its `blur_px` (pixels; None: any) on a mesh of its `depth_config` (`check_depth_config`;
    needs `frame`), and valid only where `patch_validity` allows (a patch whose rays did not walk
    cannot be described) (TypeError / ValueError naming `patches`)."""
    if not isinstance(patches, PolarPatches):
        raise TypeError(f"patches: expected PolarPatches, got {type(patches).__name__}")
    if len(patches) != len(xy):
        raise ValueError(f"patches: hold {len(patches)} keypoints, but {len(xy)} keypoints were given")
    if not np.array_equal(patches.keypoints, xy):
        raise ValueError("patches: computed for other keypoints (or another order) than the keypoints given")
    if radius is not None and not np.isclose(patches.radius, radius, rtol=1e-6, atol=0.0):
        raise ValueError(f"patches: computed with radius {patches.radius:g} m, but the descriptor's radius is "
                         f"{radius:g} m; compute them with radius={radius:g} or build the descriptor with "
                         f"radius={patches.radius:g}")
    fingerprint = frame_fingerprint(frame) if frame is not None else None  # one CRC of the depth for both checks
    if frame is not None and patches.source is not None and patches.source != patch_source(frame, fingerprint):
        raise ValueError("patches: computed on another frame (its depth, intrinsics or image differ from this "
                         "frame's); compute them on this frame, or leave patches out")
    recorded = getattr(patches, "blur_px", None)
    if blur_px is not None and recorded is not None and not np.isclose(recorded, blur_px, rtol=1e-6, atol=1e-9):
        raise ValueError(f"patches: sampled with blur_px={recorded:g}, but the descriptor's blur_px is {blur_px:g}; "
                         f"compute them with blur_px={blur_px:g}, or build the descriptor with blur_px={recorded:g}")
    if frame is not None:
        check_depth_config(getattr(patches, "depth_config", None), depth_config, frame, "patches", fingerprint)
    reached = np.asarray(patches.rings_reached)
    if reached.ndim != 2 or reached.shape[0] != len(patches):
        raise ValueError(f"patches: rings_reached must be (N, A) with N = {len(patches)}, got shape {reached.shape}")
    unwalked = np.flatnonzero(np.asarray(patches.valid, bool) & ~patch_validity(reached))
    if len(unwalked):
        raise ValueError(f"patches: {len(unwalked)} marked valid (e.g. #{unwalked[0]}) whose rays reach the first "
                         f"ring in fewer than {MIN_DIRECTION_SHARE:.0%} of their directions (no surface under them, "
                         "or they leave it at once); mark them invalid (patch_validity)")
    return patches


def check_mesh_shape(mesh: GridMesh, frame: RGBDFrame, fingerprint: tuple | None = None) -> None:
    """A prebuilt mesh must be of this frame: of its size, and, when the mesh knows its `source`, of
    its depth and intrinsics (a mesh of the frame rotated by 180 degrees has the same size) (ValueError
    naming `mesh` otherwise). `fingerprint`: the frame's `frame_fingerprint`, when already computed."""
    if tuple(mesh.image_shape) != tuple(frame.shape):
        raise ValueError(f"mesh: built for a {mesh.image_shape} frame, not this {frame.shape} one")
    source = getattr(mesh, "source", None)
    if source is not None and source != (fingerprint if fingerprint is not None else frame_fingerprint(frame)):
        raise ValueError("mesh: built from another frame (its depth or intrinsics differ from this frame's); "
                         "build it with build_mesh(frame), or leave mesh out")


#: Added to every keypoint's mesh position before the walk (mesh pixels, x and y): keeps starts off
#: the mesh's vertices and edges. The GPU walk starts from the same points (`walk_starts`).
START_OFFSET_PX = (1.3e-6, 0.7e-6)
#: A patch is valid when at least this share of its directions reach the first ring (`patch_validity`,
#: also the GPU path's rule).
MIN_DIRECTION_SHARE = 0.5


def walk_starts(mesh, keypoints: np.ndarray) -> np.ndarray:
    """(N, 2) float64 mesh pixel coordinates where the walk starts for (N, 2) image `keypoints`:
    `mesh.image_to_mesh` plus `START_OFFSET_PX`, or minus it where the plus would leave the grid (a
    keypoint on its last vertex column or row: pushed off the grid, it had no surface, while one on
    the first column kept half of its patch); shared by the CPU and GPU paths."""
    at = mesh.image_to_mesh(keypoints)
    H, W = mesh.image_shape
    sx, sy = mesh.scale
    last = np.array([int(round(W * sx)) - 1, int(round(H * sy)) - 1], np.float64)  # the grid's last vertex
    offset = np.array(START_OFFSET_PX)
    return np.where(at + offset > last, at - offset, at + offset)


def patch_validity(rings_reached: np.ndarray) -> np.ndarray:
    """(N, A) rings reached per direction -> (N,) bool: at least half of the directions reach the
    first ring. A keypoint at the edge of the surface (a silhouette, a hole) keeps the half of its
    patch that lies on the surface, with the rays that leave it repeating their last surface point;
    one with surface in fewer than half of its directions is not described."""
    if rings_reached.shape[0] == 0:
        return np.zeros(0, bool)
    return (rings_reached >= 1).mean(axis=1) >= MIN_DIRECTION_SHARE


#: The largest sampling blur accepted, pixels (a larger one blurs the patch away).
MAX_BLUR_PX = 20.0


def check_blur_px(blur_px) -> None:
    """A sampling blur of 0 to `MAX_BLUR_PX` pixels (ValueError naming `blur_px` otherwise); the GPU
    path (`geofeat.gpu.polar_patches_cuda`) checks it the same way."""
    if isinstance(blur_px, bool) or not isinstance(blur_px, numbers.Real) or not 0 <= blur_px <= MAX_BLUR_PX:
        raise ValueError(f"blur_px: expected a Gaussian blur of 0 to {MAX_BLUR_PX} pixels, got {blur_px!r}")


def sampling_image(frame: RGBDFrame, blur_px: float = SAMPLING_BLUR_PX) -> np.ndarray:
    """The gray image that patches are read from: (H, W) float32, lightly blurred against aliasing
    (a Gaussian of `blur_px` pixels, 0 = none)."""
    check_blur_px(blur_px)
    if blur_px <= 0:
        return frame.image
    return cv2.GaussianBlur(frame.image, (0, 0), blur_px)


def sample_bilinear(image: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """Bilinear intensities of an (H, W) float32 image at (..., 2) pixel coordinates (x, y);
    coordinates off the image take the nearest border value."""
    image = np.asarray(image)
    # cv2.remap would read a colour image's channels as interleaved samples, and an integer one
    # would come back rounded in its own range
    if image.ndim != 2 or image.dtype.kind != "f":
        raise ValueError(f"image: expected an (H, W) float gray image, got shape {image.shape} {image.dtype}")
    coords = np.asarray(coords)
    if coords.ndim == 0 or coords.shape[-1] != 2:
        raise ValueError(f"coords: expected (..., 2) pixel coordinates (x, y), got shape {coords.shape}")
    shape = coords.shape[:-1]
    flat = np.ascontiguousarray(coords.reshape(-1, 2), dtype=np.float32)  # no copy for float32 patches
    if flat.shape[0] == 0:
        return np.zeros(shape, np.float32)
    # cv2.remap needs maps under 32767 rows and columns: lay the points out 1024 per row (a view
    # when the count is a multiple of 1024, as for 32 x 32 patches; zero padded otherwise)
    width = 1024
    rows = -(-flat.shape[0] // width)
    if rows * width == flat.shape[0]:
        maps = flat.reshape(rows, width, 2)
    else:
        padded = np.zeros((rows * width, 2), np.float32)
        padded[: flat.shape[0]] = flat
        maps = padded.reshape(rows, width, 2)
    out = cv2.remap(image, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = out.reshape(-1)[: flat.shape[0]]
    return out.reshape(shape)


def polar_patches(
    frame: RGBDFrame,
    keypoints,
    radius: float = DEFAULT_RADIUS_M,
    n_angles: int = N_ANGLES,
    n_rings: int = N_RINGS,
    depth_config: DepthConfig | str = "auto",
    mesh: GridMesh | None = None,
    blur_px: float = SAMPLING_BLUR_PX,
) -> PolarPatches:
    """Geodesic polar patches of `keypoints` on `frame` (see module docstring).

    Args:
        frame: the RGB-D frame.
        keypoints: (N, 2) pixel coordinates (x, y), a list of cv2.KeyPoint, or `Keypoints`.
        radius: geodesic radius of the outer ring, metres.
        n_angles, n_rings: patch size (columns, rows).
        depth_config: depth preprocessing, a `DepthConfig` or a profile name ("auto": chosen from
            the frame's measured depth noise, see `geofeat.depth_profile`); ignored when `mesh` is given.
        mesh: a prebuilt `build_mesh(frame, ...)`; by default the frame's mesh for `depth_config`,
            built on the first call and cached on the frame (`geofeat.geodesic.mesh.frame_mesh`).
        blur_px: Gaussian blur of the gray image before sampling, pixels.
    """
    kp = check_patch_request(frame, keypoints, radius, n_angles, n_rings)
    if mesh is None:
        mesh = frame_mesh(frame, depth_config)  # checked against the frame's fingerprint, which it carries
        source = mesh.source
    else:
        source = frame_fingerprint(frame)
        check_mesh_shape(mesh, frame, source)
    starts = walk_starts(mesh, kp)  # kept off vertices/edges
    local, edges = mesh.walk_tables
    samples, coords, reached, _ = walk_polar(
        mesh.points, mesh.face_ok, mesh.normals, local, edges, starts, frame.K, float(radius), int(n_angles),
        int(n_rings), MAX_CROSSINGS,
    )
    valid = patch_validity(reached)
    invalid = ~valid
    # sample every patch in one call (boolean-indexed copies of the (N, R, A, 2) coordinates cost
    # more than the sampling itself), with finite stand-ins for the invalid ones, then blank those
    coords[invalid] = -1.0
    values = sample_bilinear(sampling_image(frame, blur_px), coords)
    values[invalid] = 0.0
    coords[invalid] = np.nan
    return PolarPatches(
        keypoints=kp,
        values=values,
        coords=coords,
        valid=valid,
        rings_reached=reached,
        points=samples,
        radius=float(radius),
        source=patch_source(frame, source),
        blur_px=float(blur_px),
        depth_config=mesh.config,
    )
