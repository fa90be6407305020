"""Depth preprocessing: hole filling, smoothing pyramid, intrinsics scaling, back-projection."""

import numpy as np
import pytest

import geofeat
from geofeat.depth import DepthConfig, backproject, fill_holes, preprocess_depth, scale_intrinsics, smooth


def ramp(shape=(200, 300)):
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    return (1.0 + 0.001 * u + 0.0005 * v).astype(np.float32)


def test_idw_fills_small_enclosed_holes_close_to_the_surface():
    truth = ramp()
    depth = truth.copy()
    depth[50:60, 80:95] = 0  # small hole: border ~54 px
    filled = fill_holes(depth)
    assert (filled[50:60, 80:95] > 0).all()
    np.testing.assert_allclose(filled[50:60, 80:95], truth[50:60, 80:95], atol=0.004)
    np.testing.assert_array_equal(filled[depth > 0], depth[depth > 0])


def test_large_and_border_holes_stay_holes():
    depth = ramp()
    depth[20:170, 20:170] = 0  # border of ~600 px >= 400
    depth[:, -10:] = 0  # touches the image border
    filled = fill_holes(depth)
    assert (filled[20:170, 20:170] == 0).all()
    assert (filled[:, -10:] == 0).all()


def test_simple_fill_and_none():
    depth = ramp()
    depth[50:55, 50:55] = 0
    simple = fill_holes(depth, method="simple")
    assert np.ptp(simple[50:55, 50:55]) == 0 and simple[52, 52] > 0
    assert (fill_holes(depth, method="none")[50:55, 50:55] == 0).all()
    with pytest.raises(ValueError, match="method"):
        fill_holes(depth, method="cubic")


def test_kinect_frame_hole_filling_reduces_missing_pixels():
    frame = geofeat.read_demo_frame()
    missing_before = (frame.depth == 0).mean()
    missing_after = (fill_holes(frame.depth) == 0).mean()
    assert 0.10 < missing_before < 0.20  # about 14 % of the Kinect frame is missing
    assert missing_after < missing_before


def test_smoothing_keeps_a_plane_and_halves_resolution():
    depth = ramp((240, 320))
    out = smooth(depth, levels=2, out_scale=0.5)
    assert out.shape == (120, 160)
    # the smoothed map samples the same linear ramp at the half-resolution pixel centres
    v, u = np.mgrid[0:120, 0:160]
    expected = 1.0 + 0.001 * (2 * u + 0.5) + 0.0005 * (2 * v + 0.5)
    interior = (slice(10, -10), slice(10, -10))
    np.testing.assert_allclose(out[interior], expected[interior], atol=1e-5)


def test_smoothing_does_not_leak_into_missing_pixels():
    depth = ramp((240, 320))
    depth[:, :100] = 0
    out = smooth(depth, levels=2, out_scale=0.5)
    assert (out[:, :45] == 0).all()
    assert (out[:, 60:] > 0).all()


def test_scaled_intrinsics_project_consistently():
    K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    Ks = scale_intrinsics(K, 0.5, 0.5)
    P = np.array([0.1, -0.05, 0.9])
    x, y = K[0, 0] * P[0] / P[2] + K[0, 2], K[1, 1] * P[1] / P[2] + K[1, 2]
    xs, ys = Ks[0, 0] * P[0] / P[2] + Ks[0, 2], Ks[1, 1] * P[1] / P[2] + Ks[1, 2]
    np.testing.assert_allclose([xs, ys], [(x + 0.5) * 0.5 - 0.5, (y + 0.5) * 0.5 - 0.5])


def test_backproject_inverts_projection():
    K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    depth = np.zeros((480, 640), np.float32)
    depth[100, 200] = 2.0
    P = backproject(depth, K)
    np.testing.assert_allclose(P[100, 200], [(200 - 319.5) / 525 * 2, (100 - 239.5) / 525 * 2, 2.0])
    assert np.isnan(P[0, 0]).all()


def test_backproject_inverts_the_walks_projection_with_skew():
    """The walk projects with K's skew (u = (fx X + s Y) / Z + cx): back-projection must invert it."""
    K = np.array([[525.0, 12.0, 319.5], [0, 530.0, 239.5], [0, 0, 1]])
    depth = np.random.default_rng(0).uniform(0.5, 2.0, (48, 64)).astype(np.float32)
    P = backproject(depth, K).reshape(-1, 3)
    u = (K[0, 0] * P[:, 0] + K[0, 1] * P[:, 1]) / P[:, 2] + K[0, 2]
    v = K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]
    vv, uu = np.mgrid[0:48, 0:64]
    np.testing.assert_allclose(np.stack([u, v], 1), np.stack([uu.ravel(), vv.ravel()], 1), atol=1e-9)


def test_constant_mode_and_config_checks():
    depth = ramp()
    out = preprocess_depth(depth, DepthConfig(constant=True))
    assert np.ptp(out[out > 0]) < 1e-6
    with pytest.raises(ValueError, match="fill"):
        DepthConfig(fill="magic")
    with pytest.raises(ValueError, match="mesh_scale"):
        DepthConfig(mesh_scale=2.0)
    with pytest.raises(ValueError, match="smooth_levels: must be a whole number"):
        DepthConfig(smooth_levels=1.5)  # was accepted, and smoothed once
    with pytest.raises(ValueError, match="max_perimeter"):
        DepthConfig(max_perimeter=-3)


def test_halving_is_the_mean_of_the_valid_pixels_of_each_block():
    """Each output pixel is the mean of the valid pixels of its 2 x 2 block, and missing where fewer
    than 2 of them are valid; odd sizes drop their last row / column."""
    from geofeat.depth import _halve

    rng = np.random.default_rng(4)
    depth = rng.uniform(0.5, 2.0, (9, 13)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.35] = 0.0
    blocks = depth[:8, :12].reshape(4, 2, 6, 2).transpose(0, 2, 1, 3).reshape(4, 6, 4).astype(np.float64)
    count = (blocks > 0).sum(-1)
    expected = np.where(count >= 2, blocks.sum(-1) / np.maximum(count, 1), 0.0)
    got = _halve(depth)
    assert got.shape == (4, 6) and got.dtype == np.float32
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=0)
    assert ((got == 0) == (count < 2)).all()


@pytest.mark.parametrize("func", [fill_holes, smooth, lambda d: backproject(d, geofeat.read_demo_frame().K)])
@pytest.mark.parametrize("depth", [np.ones((0, 5), np.float32), np.ones(5, np.float32), np.ones((5, 5, 1), np.float32)],
                         ids=["empty", "1d", "3d"])
def test_depth_functions_refuse_what_is_not_a_depth_map(func, depth):
    # an empty map used to crash the whole process (segfault in OpenCV's labelling) in fill_holes;
    # other shapes gave "not enough values to unpack"
    with pytest.raises(ValueError, match="depth: "):
        func(depth)


def test_fill_and_smooth_refuse_nan_for_missing_depth():
    depth = ramp((40, 40))
    depth[10:13, 10:13] = np.nan  # the NaN-for-missing convention: was left as NaN, and spread by smoothing
    for func in (fill_holes, smooth):
        with pytest.raises(ValueError, match="use 0 for missing"):
            func(depth)


@pytest.mark.parametrize("kwargs", [dict(levels=-1), dict(levels=1.5), dict(window=0), dict(out_scale=-1.0),
                                    dict(out_scale=0.0), dict(out_scale=float("nan"))])
def test_smooth_refuses_meaningless_parameters(kwargs):
    # levels=-1 silently skipped the smoothing, out_scale=-1 gave a 2x2 map, window=0 an OpenCV assertion
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        smooth(ramp((40, 40)), **kwargs)


def test_a_frame_not_a_multiple_of_four_keeps_its_depth_in_place():
    """The smoothing pyramid drops an odd last row or column at each halving, so the map covers only
    part of a 643 x 483 frame; a plain resize stretched it over the whole frame (3 mm median error
    on this tilted plane). It must be put back where it belongs, like a 640 x 480 frame's."""
    from geofeat.depth import PROFILES, preprocess_depth

    def error_mm(H, W):
        x = np.arange(W, dtype=np.float64)
        depth = np.tile(1.0 + 0.002 * x, (H, 1)).astype(np.float32)  # a plane tilted along x
        mesh_depth = preprocess_depth(depth, PROFILES["kinect"])
        Wm = mesh_depth.shape[1]
        xm = (np.arange(Wm) + 0.5) / (Wm / W) - 0.5  # the frame column of each mesh column
        row = mesh_depth[mesh_depth.shape[0] // 2]
        return 1e3 * float(np.median(np.abs(row - (1.0 + 0.002 * xm))))

    for H, W in ((480, 640), (483, 643), (481, 641), (482, 642)):
        assert error_mm(H, W) < 0.01, (H, W)


def test_the_gpu_pyramid_equals_the_cpu_one_on_a_frame_it_does_not_cover():
    torch = pytest.importorskip("torch")
    from geofeat.depth import smooth
    from geofeat.gpu import smooth_depth_torch

    rng = np.random.default_rng(0)
    depth = (1.0 + 0.1 * rng.random((483, 643))).astype(np.float32)
    depth[100:140, 200:260] = 0.0  # a hole
    cpu = smooth(depth, 2, 0.5)
    gpu = smooth_depth_torch(torch.from_numpy(depth), 2, 0.5).numpy()
    assert gpu.shape == cpu.shape and np.array_equal(gpu > 0, cpu > 0)
    assert np.abs(gpu - cpu).max() < 1e-6


@pytest.mark.parametrize("shape", [(1, 1), (1, 640), (640, 1), (2, 2)])
def test_a_depth_map_one_pixel_high_or_wide_smooths_to_no_depth_on_the_cpu_and_the_gpu(shape):
    """The smallest mesh grid (2 x 2) stretched one row of depth into a cell: a surface that is not
    there, on which polar patches were walked. Such a map now gives no depth (no face), on the CPU and
    in the GPU's pyramid alike; a 2 x 2 map keeps its depth."""
    torch = pytest.importorskip("torch")
    from geofeat.depth import smooth
    from geofeat.gpu import smooth_depth_torch

    depth = np.full(shape, 1.0, np.float32)
    for levels, scale in ((2, 0.5), (0, 1.0)):
        cpu = smooth(depth, levels, scale)
        gpu = smooth_depth_torch(torch.from_numpy(depth), levels, scale).numpy()
        assert cpu.shape == gpu.shape and min(cpu.shape) >= 2
        assert np.array_equal(cpu, gpu)
        assert (cpu > 0).all() if min(shape) >= 2 else not cpu.any()


@pytest.mark.parametrize("kwargs", [dict(power=float("nan")), dict(power=-1.0), dict(power=0.0),
                                    dict(max_perimeter=-1), dict(max_perimeter=2.5)])
def test_fill_holes_refuses_meaningless_parameters(kwargs):
    # power=NaN wrote NaN into the filled hole (refused later by smooth as "depth: contains NaN"),
    # power=-1 weighted the far border pixels most; max_perimeter as DepthConfig checks it
    depth = ramp((40, 40))
    depth[18:21, 18:21] = 0.0
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        fill_holes(depth, **kwargs)


def test_backproject_gives_nan_for_infinite_depth():
    """Missing pixels give NaN (the docstring); an infinite depth (disparity 0) gave +-inf and NaN
    coordinates mixed, points no surface has."""
    depth = ramp((6, 8)).astype(np.float64)
    depth[2, 3] = np.inf
    points = backproject(depth, geofeat.read_demo_frame().K)
    assert np.isnan(points[2, 3]).all()
    assert np.isfinite(np.delete(points.reshape(-1, 3), 2 * 8 + 3, axis=0)).all()


def _fill_holes_reference(depth, max_perimeter, method, power=2.3):
    """The hole rule of `fill_holes` written plainly with SciPy's labelling, one hole at a time."""
    from scipy import ndimage

    out = depth.astype(np.float32).copy()
    missing = depth <= 0
    labels, n = ndimage.label(missing)  # 4-connected by default
    H, W = depth.shape
    for index in range(1, n + 1):
        hole = labels == index
        ys, xs = np.nonzero(hole)
        if ys.min() == 0 or xs.min() == 0 or ys.max() == H - 1 or xs.max() == W - 1:
            continue
        border = ndimage.binary_dilation(hole, np.ones((3, 3), bool)) & ~missing
        by, bx = np.nonzero(border)
        if len(by) >= max_perimeter:
            continue
        bz = depth[by, bx].astype(np.float64)
        for y, x in zip(ys, xs):
            if method == "simple":
                out[y, x] = bz.mean()
            else:
                w = ((y - by) ** 2 + (x - bx) ** 2).astype(np.float64) ** (-power / 2)
                out[y, x] = (w * bz).sum() / w.sum()
    return out


@pytest.mark.parametrize("method", ["idw", "simple"])
def test_fill_holes_follows_its_rule_on_many_holes(method):
    """The compiled hole filler against a plain SciPy version of the same rule, on random maps with
    hundreds of holes of every size, some on the border, and several perimeter limits: the same
    pixels filled, the same values (float32 rounding of the float64 sums' order)."""
    rng = np.random.default_rng(11)
    for shape, share in (((60, 80), 0.3), ((45, 33), 0.55), ((30, 50), 0.08)):
        depth = (0.5 + 3 * rng.random(shape)).astype(np.float32)
        depth[rng.random(shape) < share] = 0
        for max_perimeter in (400, 12, 1, 0):
            got = fill_holes(depth, max_perimeter, method)
            ref = _fill_holes_reference(depth, max_perimeter, method)
            np.testing.assert_array_equal(got > 0, ref > 0)
            np.testing.assert_allclose(got, ref, rtol=1e-6, atol=0)
            if max_perimeter == 400:
                assert (got > 0).sum() > (depth > 0).sum()  # something was filled
