"""Depth profiles: the noise statistic, the automatic choice, and where a profile can be named."""

from __future__ import annotations

import json

import numpy as np
import pytest

import geofeat
from geofeat.depth import PROFILES, check_profile, depth_noise, depth_profile, resolve_depth_config
from geofeat.io import read_sequence, write_frame, write_intrinsics
from geofeat.sim.noise import kinect_depth_noise
from surfaces import K_VGA, corresponding_points, sheet_pair


def _sphere_cap(z0: float = 0.9, radius: float = 0.12, shape=(240, 320)) -> np.ndarray:
    """Depth (metres) of a sphere of `radius` bulging towards a camera with K_VGA/2, on a plane at z0."""
    H, W = shape
    fx, cx, cy = K_VGA[0, 0] / 2, W / 2, H / 2
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    x, y = (u - cx) / fx, (v - cy) / fx
    # ray (x, y, 1) t hits the sphere centred at (0, 0, z0) when |t r - c|^2 = radius^2
    a = x**2 + y**2 + 1
    disc = z0**2 - a * (z0**2 - radius**2)
    t = np.where(disc > 0, (z0 - np.sqrt(np.maximum(disc, 0))) / a, z0)
    return t.astype(np.float64), np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])


def test_noise_statistic_ignores_curvature_and_measures_noise():
    depth, K = _sphere_cap()
    clean = depth_noise(depth, K)
    assert clean.slope_noise < 0.02 and clean.windows > 50_000  # a smooth curved surface is not noise
    assert clean.quantisation_step < 1e-4  # continuous depth: no millimetre steps
    rng = np.random.default_rng(0)
    for sigma in (0.0005, 0.002):
        noisy = depth + rng.normal(0, sigma, depth.shape)
        footprint = np.median(depth) / K[0, 0]
        measured = depth_noise(noisy, K).slope_noise
        assert measured == pytest.approx(sigma / footprint, rel=0.2), (sigma, measured)
        assert depth_noise(noisy, K).relative_noise == pytest.approx(sigma / np.median(depth), rel=0.2)


def test_auto_picks_kinect_on_the_real_frame_and_clean_on_clean_depth():
    kinect = geofeat.read_demo_frame()
    assert depth_profile(kinect) == "kinect"
    flat, bent, *_ = sheet_pair(bend_radius=0.1)
    assert depth_profile(bent) == "clean"
    # the same bent sheet with the simulator's Kinect noise model
    cos_view = np.ones_like(bent.depth)
    noisy = kinect_depth_noise(bent.depth, cos_view, np.random.default_rng(0), n_blobs=0)
    assert depth_profile(geofeat.RGBDFrame(bent.image, noisy, bent.K)) == "kinect"
    # noise-free depth stored in 0.1 mm steps (what the simulator writes) stays clean; in 1 mm steps
    # (half a pixel footprint at 1 m) the staircase is coarse enough for one round of smoothing
    for unit, expected in ((0.0001, "clean"), (0.001, "quantised")):
        quantised = (np.round(bent.depth / unit) * unit).astype(np.float32)
        noise = depth_noise(quantised, bent.K)
        assert unit * 0.99 <= noise.quantisation_step <= 2.5 * unit  # fine steps are not all occupied
        assert noise.slope_noise < 0.05  # the step itself is not counted as sensor noise
        assert depth_profile(geofeat.RGBDFrame(bent.image, quantised, bent.K)) == expected, noise


def test_quantised_profile_follows_the_surface_under_millimetre_steps():
    """Noise-free depth stored in millimetres (the public layout) at 1 m: the "quantised" profile's
    samples lie closer to those of the exact surface than both other profiles' (the full-resolution
    mesh follows the staircase, the kinect one smooths the bend away)."""
    _, bent, flat_sheet, bent_sheet = sheet_pair(bend_radius=0.12)
    _, xy = corresponding_points(flat_sheet, bent_sheet, n=60)
    exact = geofeat.polar_patches(bent, xy, depth_config="clean")
    mm = geofeat.RGBDFrame(bent.image, (np.round(bent.depth / 0.001) * 0.001).astype(np.float32), bent.K)
    assert depth_profile(mm) == "quantised"
    error = {}
    for profile in ("quantised", "kinect", "clean"):
        got = geofeat.polar_patches(mm, xy, depth_config=profile)
        assert got.valid.all() and exact.valid.all()
        error[profile] = np.linalg.norm(got.coords - exact.coords, axis=-1).mean()  # pixels
    assert error["quantised"] < 0.06, error  # measured 0.04
    assert error["quantised"] < 0.5 * min(error["kinect"], error["clean"]), error  # 0.13 and 0.19


def test_depth_profile_is_the_rule_on_depth_noise():
    """depth_profile stops at the window count when it decides; its answer must be the rule
    applied to the full depth_noise, for each way of deciding."""
    from geofeat.depth import MIN_NOISE_WINDOWS, SLOPE_NOISE_THRESHOLD, STEP_THRESHOLD

    _, bent, *_ = sheet_pair(bend_radius=0.1)
    noisy = kinect_depth_noise(bent.depth, np.ones_like(bent.depth), np.random.default_rng(0), n_blobs=0)
    tiny = np.zeros_like(bent.depth)
    tiny[100:110, 100:130] = 1.0  # 6 x 26 = 156 measurable windows
    depths = [bent.depth, noisy, tiny] + [(np.round(bent.depth / u) * u).astype(np.float32) for u in (0.0001, 0.001)]
    answers = []
    for depth in depths:
        noise = depth_noise(depth, bent.K)
        rule = ("kinect" if noise.windows < MIN_NOISE_WINDOWS or noise.slope_noise > SLOPE_NOISE_THRESHOLD
                else "quantised" if noise.step_per_footprint > STEP_THRESHOLD else "clean")
        answers.append(depth_profile(geofeat.RGBDFrame(bent.image, depth, bent.K)))
        assert answers[-1] == rule, noise
    assert answers == ["clean", "kinect", "kinect", "clean", "quantised"]  # every branch was taken


def test_auto_default_equals_the_profile_it_picks():
    _, bent, _, sheet = sheet_pair(bend_radius=0.1)
    xy = np.array([[300.0, 240.0], [340.5, 250.2]])
    auto = geofeat.polar_patches(bent, xy)
    clean = geofeat.polar_patches(bent, xy, depth_config="clean")
    kinect = geofeat.polar_patches(bent, xy, depth_config="kinect")
    assert np.array_equal(auto.values, clean.values)
    assert not np.allclose(kinect.values, clean.values)  # the profiles really differ
    assert resolve_depth_config("kinect") == PROFILES["kinect"] and PROFILES["clean"].mesh_scale == 1.0


def test_unknown_profiles_are_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="depth_profile: expected one of auto, kinect, quantised, clean"):
        check_profile("smooth")
    with pytest.raises(ValueError, match="depth_config"):
        geofeat.GeoBit(depth_config="kinnect")
    with pytest.raises(ValueError, match="depth_config.*auto.*frame"):
        resolve_depth_config("auto")
    frame = geofeat.read_demo_frame()
    write_intrinsics(tmp_path / "intrinsics.xml", frame.K)
    write_frame(tmp_path, "a-ref", frame.color, frame.depth)
    (tmp_path / "geofeat.json").write_text(json.dumps({"depth_profile": "noisy"}))
    with pytest.raises(ValueError, match="geofeat.json: depth_profile"):
        read_sequence(tmp_path)
    (tmp_path / "geofeat.json").write_text(json.dumps({"depth_profile": "clean", "radius": 0.05}))
    seq = read_sequence(tmp_path)
    assert seq.depth_profile == "clean" and seq.radius == 0.05  # the bench and the applications use seq.radius


@pytest.mark.parametrize("K", [np.eye(2), np.array([[np.nan, 0, 80], [0, 150, 60], [0, 0, 1]]),
                               np.array([[-150.0, 0, 80], [0, 150, 60], [0, 0, 1]])])
def test_depth_noise_refuses_a_bad_camera_matrix(K):
    """depth_noise divides by fx: a matrix that is not a pinhole K is an error, not a number."""
    with pytest.raises(ValueError, match="K: "):
        depth_noise(np.ones((40, 40)), K)


def test_depth_profile_of_a_bare_depth_map_is_a_type_error():
    depth, _ = _sphere_cap()
    with pytest.raises(TypeError, match="RGBDFrame.*depth_noise"):
        depth_profile(depth)


def test_depth_noise_of_an_empty_map_is_an_error():
    with pytest.raises(ValueError, match="depth: empty"):
        depth_noise(np.zeros((0, 5)), K_VGA)


def test_depth_noise_reads_infinite_depth_as_missing_like_nan():
    """Depth from disparity holds inf where the disparity is 0. NaN was already read as missing; inf
    counted as depth, so every statistic became NaN (and the holes 0 %) without a word."""
    depth, K = _sphere_cap()
    holes = np.zeros(depth.shape, bool)
    holes[100:130, 150:200] = True
    expected = depth_noise(np.where(holes, 0.0, depth), K)
    for missing in (np.nan, np.inf):
        got = depth_noise(np.where(holes, missing, depth), K)
        assert got == expected


def _kinect_sequence_naming(folder, profile):
    """The shipped Kinect frame (measured: kinect) as a one-frame sequence whose geofeat.json names `profile`."""
    frame = geofeat.read_demo_frame()
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder / "intrinsics.xml", frame.K)
    write_frame(folder, "a-ref", frame.color, frame.depth)
    (folder / "geofeat.json").write_text(json.dumps({"depth_profile": profile}))
    return folder


def test_an_explicit_auto_measures_even_where_geofeat_json_names_a_profile(tmp_path, capsys):
    """`--depth-profile auto` was read as "not given", so geofeat.json's profile won over it; now None
    is the default (geofeat.json's, else measured) and "auto" always measures."""
    from geofeat.cli import main
    from geofeat.depth import sequence_depth_profile

    seq = read_sequence(_kinect_sequence_naming(tmp_path / "s", "clean"))
    assert sequence_depth_profile(seq) == sequence_depth_profile(seq, None) == "clean"
    assert sequence_depth_profile(seq, "auto") == "kinect"  # measured on the noisy Kinect depth
    assert sequence_depth_profile(seq, "quantised") == "quantised"
    common = ["extract", str(tmp_path / "s"), "--descriptor", "orb", "--keypoints", "50"]
    assert main(common + ["--out", str(tmp_path / "a.h5")]) == 0
    assert "depth profile clean," in capsys.readouterr().out
    assert main(common + ["--out", str(tmp_path / "b.h5"), "--depth-profile", "auto"]) == 0
    assert "depth profile kinect," in capsys.readouterr().out
    assert main(common + ["--out", str(tmp_path / "c.h5"), "--depth-profile", "Quantised"]) == 0
    assert "depth profile quantised," in capsys.readouterr().out


def test_depth_noise_of_non_square_pixels_does_not_change_with_a_quarter_roll():
    """The pixel footprint was z / fx: with fx = 1.2 fy the same camera rolled by a quarter turn (fx
    and fy swap) measured a fifth more or less slope noise and step per footprint, and could pick
    another depth profile. The footprint is z over the mean of fx and fy now."""
    H, W = 120, 160
    K = np.array([[1.2 * 150.0, 0, (W - 1) / 2], [0, 150.0, (H - 1) / 2], [0, 0, 1]])
    rng = np.random.default_rng(0)
    depth = np.round((1.0 + 0.002 * rng.standard_normal((H, W))) / 0.001) * 0.001  # millimetre steps
    frame = geofeat.RGBDFrame(np.zeros((H, W), np.float32), depth.astype(np.float32), K)
    turned = frame.rotated90(1)
    a, b = depth_noise(frame.depth, frame.K), depth_noise(turned.depth, turned.K)
    assert b.slope_noise == pytest.approx(a.slope_noise, rel=1e-3)
    assert b.step_per_footprint == pytest.approx(a.step_per_footprint, rel=1e-3)
    assert a.step_per_footprint == pytest.approx(0.001 / (1.0 / 165.0), rel=0.02)  # f = (180 + 150) / 2
