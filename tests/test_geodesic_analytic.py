"""The geodesic mapping f(.) sample by sample against surfaces whose geodesics are known exactly
(`geodesic_truth`): a plane, a cylinder and a cone (developable: unrolled, the rays are straight
lines) and a sphere (great circles), seen obliquely by a camera with fx != fy and an off-centre
principal point. Noise-free depth on a full-resolution mesh, so that what is measured is the walk
(and its angle convention), not the depth preprocessing.

Measured (320 x 240, fx = 280, fy = 250, surfaces 0.9-1.3 m away, 75 mm radius, 4 keypoints, every
ray reaching its 32 rings): max error of the 3D samples 0.003 mm on the plane, 0.18 mm on the
cylinder (R = 0.25 m), 0.21 mm on the cone, 0.23 mm on the sphere (R = 0.3 m), the error of a
piecewise-flat mesh of a curved surface; in the image 0.0005 px (plane) and under 0.05 px (curved).
One column (11.25 degrees) at the outer ring is 15 mm, one ring 2.3 mm.
"""

import numpy as np
import pytest

import geofeat
from geofeat.depth import DepthConfig
from geodesic_truth import Cone, Cylinder, Plane, Sphere, exact_samples, project, render

EXACT_MESH = DepthConfig(fill="none", smooth_levels=0, mesh_scale=1.0)
K_ODD = np.array([[280.0, 0.0, 171.3], [0.0, 250.0, 112.6], [0.0, 0.0, 1.0]])  # fx != fy, off-centre
SHAPE = (240, 320)
KEYPOINTS = np.array([[160.3, 120.6], [120.2, 90.9], [200.7, 150.1], [185.5, 95.2]])

SURFACES = {  # surface, tolerance of the 3D samples (mm), of their image coordinates (px)
    "plane tilted 55 deg": (Plane([0, 0, 1.0], [0.45, 0.6, -0.66]), 0.02, 0.005),
    "cylinder, oblique axis": (Cylinder([0, 0, 1.25], [0.3, 1, 0.2], 0.25), 0.6, 0.15),
    "cone, oblique axis": (Cone([-0.4, -0.3, 1.2], [1, 0.7, 0.1], np.radians(25)), 0.6, 0.15),
    "sphere": (Sphere([0.02, -0.01, 1.3], 0.3), 0.6, 0.15),
}


@pytest.mark.parametrize("name", list(SURFACES))
def test_samples_lie_on_the_exact_geodesics(name):
    surface, tol_mm, tol_px = SURFACES[name]
    frame = render(surface, K_ODD, SHAPE)
    P = geofeat.polar_patches(frame, KEYPOINTS, radius=0.075, depth_config=EXACT_MESH)
    assert P.valid.all() and (P.rings_reached == 32).all()  # every sample is compared
    exact = exact_samples(surface, K_ODD, KEYPOINTS, 0.075)
    err_mm = np.linalg.norm(P.points - exact, axis=-1) * 1000
    err_px = np.linalg.norm(P.coords - project(K_ODD, exact), axis=-1)
    assert err_mm.max() < tol_mm, f"{name}: samples up to {err_mm.max():.3f} mm off the exact geodesics"
    assert err_px.max() < tol_px, f"{name}: samples up to {err_px.max():.3f} px off in the image"


def test_on_a_plane_column_0_stays_on_the_keypoints_image_row_and_quarter_turns_go_up():
    """A plane's straight lines are straight in the image: the ray of column 0 (image +x projected
    onto the surface) keeps the keypoint's image row and moves right; column A/4 moves up, column
    A/2 left, column 3A/4 down, whatever the slant."""
    surface = SURFACES["plane tilted 55 deg"][0]
    frame = render(surface, K_ODD, SHAPE)
    P = geofeat.polar_patches(frame, KEYPOINTS, radius=0.075, depth_config=EXACT_MESH)
    d = P.coords - KEYPOINTS[:, None, None, :]  # (N, R, A, 2) image offsets of the samples
    assert np.abs(d[:, :, 0, 1]).max() < 1e-3 and (d[:, :, 0, 0] > 0).all()
    assert (d[:, :, 8, 1] < 0).all() and (d[:, :, 16, 0] < 0).all() and (d[:, :, 24, 1] > 0).all()
    assert np.abs(d[:, :, 16, 1]).max() < 1e-3


# A known limitation, measured in the review of f(.) (docs/concepts.md, the depth profiles): its fix changes
# the patches of ordinary frames (the shipped Kinect frame among them), and the one tried (cutting the
# mesh where the raw depth steps) cost real-data matches (BENCHMARKS.md, "Depth steps cut from the mesh").

@pytest.mark.xfail(strict=True, reason=(
    "the smoothing pyramid of the 'kinect' and 'quantised' profiles averages across depth edges: a "
    "cloth 5-20 cm in front of a wall becomes one ramped surface that the 8-footprint edge cut no "
    "longer sees, and rays walk onto the wall (cloth 0.9 m, wall 1.0 m: 755 of 1024 samples of a "
    "keypoint 5 px from the edge lie over 5 mm behind the cloth; on the shipped Kinect frame 169 of "
    "664 valid SIFT keypoints have samples over 5 cm off the measured depth, none with 'clean')"))
def test_rays_do_not_walk_onto_the_wall_behind_a_smoothed_silhouette():
    K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    depth = np.full((480, 640), 1.0, np.float32)
    depth[:, :320] = 0.9  # the cloth on the left, 10 cm in front of the wall
    frame = geofeat.RGBDFrame(np.random.default_rng(0).random((480, 640)).astype(np.float32), depth, K)
    P = geofeat.polar_patches(frame, np.array([[315.3, 240.2], [310.3, 240.2]]), depth_config="kinect")
    assert P.valid.all()
    assert np.nanmax(P.points[..., 2]) < 0.91, f"samples up to {np.nanmax(P.points[..., 2]):.3f} m deep"
