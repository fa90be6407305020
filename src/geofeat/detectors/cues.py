"""Per-pixel cues of an RGB-D frame that tell a keypoint that stays put on a bending surface from one
that slides along a fold edge, a silhouette or a foreshortened slope.

Every cue is a dense (H, W) float32 map computed with a few OpenCV filters (no Python loops), read
at the candidate keypoints by `cue_features`. Image cues are on the gray image in [0, 1]; depth cues
are in units of the pixel footprint (z / fx across, z / fy down), so they do not depend on the distance
to the camera.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..depth import depth_steps
from ..frame import RGBDFrame

#: A depth discontinuity: a raw-depth step of more than this many pixel footprints between neighbours.
DEPTH_STEP_FOOTPRINTS = 4.0

#: Image cues: the scorer combines them linearly, so that its ranking of corners follows their
#: contrast and cornerness the same way in every view (a non-linear mix of image cues learned on
#: simulated renders ranked the same corner differently in two views of a bent sheet).
IMAGE_CUES = (
    "level",            # pyramid level of the candidate (0 = full resolution, 1 = half)
    "log_eig_3",        # log of the structure tensor's smaller eigenvalue, 3 x 3 window
    "log_eig_7",        # the same, 7 x 7 window
    "log_grad_1",       # log gradient magnitude after a sigma = 1 px blur
    "log_grad_3",       # after a sigma = 3 px blur
    "log_dog",          # log |difference of Gaussians| (sigma 1.6 - sigma 1)
    "log_std_9",        # log local standard deviation in a 9 x 9 window
    "log_std_21",       # in a 21 x 21 window
)
#: Geometry cues from the depth, in pixel footprints: the scorer's small MLP learns from them where
#: points slide or disappear (folds, silhouettes, steep slopes).
CONTEXT_CUES = (
    "valid_frac_31",    # fraction of pixels with depth in a 31 x 31 window
    "slope",            # depth slope in pixel footprints per pixel (0 = facing the camera)
    "log_curv_2",       # log |Laplacian of depth| in footprints, sigma = 2 px
    "log_curv_6",       # sigma = 6 px
    "log_edge_dist",    # log(1 + distance in px to the nearest depth discontinuity or hole)
)
#: Names of the columns of `cue_features`, in order.
CUE_NAMES = IMAGE_CUES + CONTEXT_CUES


def _log(x: np.ndarray, eps: float) -> np.ndarray:
    return np.log(np.abs(x) + eps).astype(np.float32)


#: eps of the "log_" cues: cue = log(|raw| + eps), taken after sampling at the candidates (cheaper).
LOG_EPS = {"log_eig_3": 1e-7, "log_eig_7": 1e-7, "log_grad_1": 1e-4, "log_grad_3": 1e-4, "log_dog": 1e-4,
           "log_std_9": 1e-4, "log_std_21": 1e-4, "log_curv_2": 1e-3, "log_curv_6": 1e-3}


def cue_maps(frame: RGBDFrame, depth_cues: bool = True) -> dict[str, np.ndarray]:
    """Dense raw cue maps of `frame`, each (H, W) float32, keyed by cue name (see `CUE_NAMES`; "level"
    is per candidate). The "log_" cues are stored before their logarithm (`LOG_EPS`). Without
    `depth_cues` the depth maps are left out (and read as 0 by `cue_features`)."""
    g = frame.image.astype(np.float32)
    H, W = g.shape
    maps: dict[str, np.ndarray] = {}
    maps["log_eig_3"] = cv2.cornerMinEigenVal(g, 3, 3)
    maps["log_eig_7"] = cv2.cornerMinEigenVal(g, 7, 3)
    g1 = cv2.GaussianBlur(g, (0, 0), 1.0)
    g16 = cv2.GaussianBlur(g, (0, 0), 1.6)
    g3 = cv2.GaussianBlur(g, (0, 0), 3.0)
    for name, img in (("log_grad_1", g1), ("log_grad_3", g3)):
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
        maps[name] = cv2.magnitude(gx, gy)
    maps["log_dog"] = g16 - g1
    for k in (9, 21):
        mean = cv2.blur(g, (k, k))
        var = np.maximum(cv2.blur(g * g, (k, k)) - mean * mean, 0.0)
        maps[f"log_std_{k}"] = np.sqrt(var)
    if not depth_cues:
        return maps

    depth = frame.depth.astype(np.float32)
    valid = (depth > 0).astype(np.float32)
    maps["valid_frac_31"] = cv2.blur(valid, (31, 31))
    # a pixel's footprint is z / fx across and z / fy down: with non-square pixels (fx != fy) the
    # steps along y are measured in y footprints, or a plane tilted about the image x axis read
    # fx / fy times steeper than the same plane tilted about y
    fx, fy = float(frame.K[0, 0]), float(frame.K[1, 1])

    def smooth_depth(sigma: float) -> np.ndarray:
        # normalised convolution: holes do not pull the depth towards 0
        num = cv2.GaussianBlur(depth * valid, (0, 0), sigma)
        den = cv2.GaussianBlur(valid, (0, 0), sigma)
        return np.where(den > 1e-3, num / np.maximum(den, 1e-3), 0.0).astype(np.float32)

    z2 = smooth_depth(2.0)
    # metres per pixel across and down (1 where there is no depth)
    footprint_x = np.where(z2 > 0, z2 / np.float32(fx), np.float32(1.0)).astype(np.float32)
    footprint_y = footprint_x if fx == fy else np.where(z2 > 0, z2 / np.float32(fy), np.float32(1.0)).astype(np.float32)
    zx = cv2.Sobel(z2, cv2.CV_32F, 1, 0, ksize=3) / 8.0 / footprint_x
    zy = cv2.Sobel(z2, cv2.CV_32F, 0, 1, ksize=3) / 8.0 / footprint_y
    slope = np.sqrt(zx * zx + zy * zy)
    maps["slope"] = np.minimum(slope, 20.0).astype(np.float32)
    maps["log_curv_2"] = _laplacian_footprints(z2, footprint_x, footprint_y)
    z6 = smooth_depth(6.0)
    maps["log_curv_6"] = _laplacian_footprints(z6, footprint_x, footprint_y)
    maps["log_edge_dist"] = depth_edge_distance(depth, fx, fy=fy)
    return maps


def _laplacian_footprints(z: np.ndarray, footprint_x: np.ndarray, footprint_y: np.ndarray) -> np.ndarray:
    """z_xx / footprint_x + z_yy / footprint_y of an (H, W) depth map (the 3 x 3 Laplacian's two second
    derivatives, each in its own axis's footprints): cv2.Laplacian(z, ksize=3) / footprint for square
    pixels, as before non-square ones were told apart."""
    if footprint_x is footprint_y:
        return cv2.Laplacian(z, cv2.CV_32F, ksize=3) / footprint_x
    return (cv2.Sobel(z, cv2.CV_32F, 2, 0, ksize=3) / footprint_x
            + cv2.Sobel(z, cv2.CV_32F, 0, 2, ksize=3) / footprint_y)


def depth_edge_distance(depth: np.ndarray, fx: float, step_footprints: float = DEPTH_STEP_FOOTPRINTS,
                        fy: float | None = None) -> np.ndarray:
    """(H, W) float32 distance, pixels, to the nearest depth discontinuity or hole.

    A discontinuity is a raw-depth step between 4-neighbouring pixels of more than
    `step_footprints` pixel footprints (depth / fx across, depth / fy down, metres per pixel): a
    silhouette or a fold that hides part of the surface. A surface inclined by an angle a to the
    image plane steps by tan(a) footprints per pixel, so 4 footprints also flags slopes steeper than
    76 degrees, 10 only those steeper than 84. A hole is depth 0.

    Args:
        depth: (H, W) depth, metres; 0 = no depth.
        fx: focal length along x, pixels.
        step_footprints: the smallest step that makes a discontinuity, pixel footprints.
        fy: focal length along y, pixels (None: fx, square pixels).
    """
    depth = np.asarray(depth, np.float32)
    right, down = depth_steps(depth, fx, fx if fy is None else fy, step_footprints)
    edge = depth <= 0
    edge[:, :-1] |= right  # a step is marked on its left or upper pixel
    edge[:-1] |= down
    np.logical_not(edge, out=edge)  # now: not an edge
    return cv2.distanceTransform(edge.view(np.uint8), cv2.DIST_L2, 3)


def cue_features(maps: dict[str, np.ndarray], xy: np.ndarray, level: np.ndarray) -> np.ndarray:
    """(N, len(CUE_NAMES)) float32: the candidates' pyramid level and the cue maps read at the
    nearest pixel of each candidate.

    Args:
        maps: from `cue_maps`.
        xy: (N, 2) candidate positions, pixels.
        level: (N,) pyramid level of each candidate.
    """
    some = next(iter(maps.values()))
    H, W = some.shape
    xi = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, W - 1)
    yi = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, H - 1)
    cols = [np.asarray(level, np.float32)]
    for name in CUE_NAMES[1:]:
        if name not in maps:
            cols.append(np.zeros(len(xi), np.float32))
            continue
        raw = maps[name][yi, xi]
        if name == "log_edge_dist":
            cols.append(np.log1p(np.minimum(raw, 200.0)))
        elif name in LOG_EPS:
            cols.append(_log(raw, LOG_EPS[name]))
        else:
            cols.append(raw)
    return np.stack(cols, axis=1).astype(np.float32)
