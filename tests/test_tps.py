"""The one thin-plate spline (`geofeat.tps`): the authors' file layout, the batched fit, and agreement
with independent references (the authors' formula written out here, scipy's RBFInterpolator)."""

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from geofeat.tps import (
    ThinPlateSpline, authors_tps, evaluate_batch, fit_tps, hartley_transform, solve_batch,
)


def authors_formula(xy: np.ndarray, theta: np.ndarray, ctrl: np.ndarray, size) -> np.ndarray:
    """The authors' published warp, term by term: p + [1, x, y] a + U w, U = d^2 log(d + 1e-6), in
    coordinates divided by (W, H)."""
    theta = theta.reshape(-1, 2).astype(float)
    T = len(ctrl)
    w, a = theta[:T], theta[T:]
    p = xy / np.asarray(size, float)
    d = np.linalg.norm(p[:, None] - ctrl[None].astype(float), axis=-1)
    return (p + np.c_[np.ones(len(p)), p] @ a + (d**2 * np.log(d + 1e-6)) @ w) * np.asarray(size, float)


def test_reading_the_authors_arrays_gives_their_warp():
    rng = np.random.default_rng(0)
    ctrl = rng.random((40, 2)).astype(np.float32)
    theta = np.concatenate([rng.normal(0, 0.02, (40, 2)), [[0.01, -0.02], [0.05, 0.01], [-0.03, 0.02]]])[None]
    xy = rng.uniform(-50, 700, (500, 2))
    spline = ThinPlateSpline.from_authors_arrays(theta.astype(np.float32), ctrl, (640, 480))
    np.testing.assert_allclose(spline(xy), authors_formula(xy, theta.astype(np.float32), ctrl, (640, 480)),
                               rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="theta"):
        ThinPlateSpline.from_authors_arrays(theta[:, :-1], ctrl, (640, 480))


def test_authors_fit_interpolates_and_round_trips_through_their_arrays():
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 320, (25, 2))
    dst = src + rng.normal(0, 5, (25, 2))
    spline = authors_tps(src, dst, (320, 240))
    np.testing.assert_allclose(spline(src), dst, atol=1e-6)
    theta, ctrl = spline.authors_arrays()
    q = rng.uniform(0, 320, (200, 2))
    # float32 storage costs ~1e-4 px at most
    np.testing.assert_allclose(authors_formula(q, theta, ctrl, (320, 240)), spline(q), atol=1e-3)
    with pytest.raises(ValueError, match="authors"):
        fit_tps(src, dst).authors_arrays()  # a Hartley-normalised spline has no such layout


def test_interpolating_spline_is_scipys_thin_plate_rbf():
    """Without smoothing the spline is the same function under any similarity normalisation: scipy's
    agrees (the authors' division by (W, H) is a similarity only when W = H)."""
    rng = np.random.default_rng(2)
    src = rng.uniform(0, 640, (60, 2))
    dst = src + 20 * np.sin(src[:, ::-1] / 100)
    q = rng.uniform(0, 640, (300, 2))
    expected = RBFInterpolator(src, dst, kernel="thin_plate_spline")(q)
    np.testing.assert_allclose(fit_tps(src, dst)(q), expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(fit_tps(src, dst, normalisation="size", size=(640, 640))(q), expected, rtol=0, atol=1e-6)
    assert np.abs(fit_tps(src, dst, normalisation="size", size=(640, 480))(q) - expected).max() > 0.1


def test_regularisation_smooths_instead_of_interpolating():
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 640, (80, 2))
    dst = src + rng.normal(0, 3, (80, 2))  # pure noise around the identity
    exact, smooth = fit_tps(src, dst), fit_tps(src, dst, regularisation=1.0)
    np.testing.assert_allclose(exact(src), dst, atol=1e-6)
    assert np.abs(smooth(src) - src).mean() < 0.5 * np.abs(dst - src).mean()


def test_batched_fit_is_the_single_fit():
    rng = np.random.default_rng(4)
    src = rng.normal(0, 1, (7, 6, 2))
    dst = src + rng.normal(0, 0.1, (7, 6, 2))
    src[3, :, 1] = 2 * src[3, :, 0]  # collinear sample
    w, a, ok = solve_batch(src, dst, 1e-3)
    assert ok.tolist() == [True] * 3 + [False] + [True] * 3
    p = rng.normal(0, 1, (50, 2))
    batch = evaluate_batch(p, src, w, a)
    I = np.eye(3)
    for b in np.flatnonzero(ok):
        single = ThinPlateSpline(src[b], w[b], a[b], I, I)
        np.testing.assert_allclose(batch[b], single(p), atol=1e-10)
    with pytest.raises(ValueError, match="collinear"):
        fit_tps(src[3], dst[3])


def test_hartley_transform():
    xy = np.random.default_rng(5).uniform(0, 500, (30, 2))
    T = hartley_transform(xy)
    p = xy @ T[:2, :2].T + T[:2, 2]
    np.testing.assert_allclose(p.mean(axis=0), 0, atol=1e-12)
    assert np.linalg.norm(p, axis=1).mean() == pytest.approx(np.sqrt(2))


def test_spline_maps_points_of_shape_m_by_2_only():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (12, 2))
    tps = fit_tps(src, src + rng.normal(0, 1, src.shape))
    grid = rng.uniform(0, 100, (3, 4, 2))
    assert np.array_equal(tps(grid), tps(grid.reshape(-1, 2)))  # any (..., 2) array is M points
    for xy in (np.ones((4, 3)), src[:3].T, np.float64(3.0)):  # (4, 3) was read as 6 points, (2, 3) as 3
        with pytest.raises(ValueError, match=r"xy: expected \(M, 2\)"):
            tps(xy)


def test_fit_refuses_negative_smoothing_and_bad_sizes():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (12, 2))
    dst = src + rng.normal(0, 1, src.shape)
    for value in (-1.0, np.nan, "1"):  # -1 gave a spline that neither interpolates nor smooths
        with pytest.raises(ValueError, match="regularisation: expected a number >= 0"):
            fit_tps(src, dst, regularisation=value)
    for size in ((0, 480), (640,), (640, 480, 3), (-640, 480)):  # ZeroDivisionError, unpacking errors
        with pytest.raises(ValueError, match=r"size: expected the image size \(W, H\)"):
            fit_tps(src, dst, normalisation="size", size=size)
    assert np.allclose(fit_tps(src, dst, regularisation=np.float32(0))(src), dst)


def test_repeated_control_points_with_two_destinations_are_refused_not_fitted_by_least_squares():
    """A point repeated with two destinations has no interpolating spline: `fit_tps` fell back to
    least squares and returned a spline 2.5 px off its own control points (docstring: 0 interpolates);
    a nearly repeated one (1e-7 px apart) gave weights of 1e14 and a warp 4e6 px away at the centre.
    With the same destination the repeat is harmless; smoothing (regularisation > 0) has a solution.
    `solve_batch` failed the whole batch (LinAlgError) on one exactly singular member."""
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (10, 2))
    dst = src + rng.normal(0, 1, src.shape)
    for gap in (0.0, 1e-7):
        s, d = np.vstack([src, src[:1] + gap]), np.vstack([dst, dst[:1] + 5])
        with pytest.raises(ValueError, match="degenerate control points"):
            fit_tps(s, d)
        assert np.isfinite(fit_tps(s, d, regularisation=1e-3)(s)).all()
    same = np.vstack([src, src[:1]]), np.vstack([dst, dst[:1]])
    np.testing.assert_allclose(fit_tps(*same)(same[0]), same[1], atol=1e-6)
    batch_src = np.stack([src[:5], np.vstack([src[:4], src[:1]])])  # the second repeats a point
    w, a, ok = solve_batch(batch_src, batch_src + 1.0, 0.0)
    assert ok.tolist() == [True, False]
    single = solve_batch(batch_src[:1], batch_src[:1] + 1.0, 0.0)
    np.testing.assert_allclose(w[0], single[0][0])
    np.testing.assert_allclose(a[0], single[1][0])


def test_a_small_cluster_of_control_points_is_not_called_collinear():
    """Whether points span the plane is a question of their shape, not of their size: with the
    authors' normalisation (division by the image size), five landmarks in a 20 px square of a
    640x480 frame were refused as "collinear or repeated" (and the ground-truth frame failed)."""
    src = np.array([[300.0, 200.0], [320.0, 200.0], [300.0, 220.0], [320.0, 220.0], [310.0, 212.0]])
    dst = src + [[1.0, 0.5], [0.5, -0.5], [-0.5, 1.0], [0.0, 0.0], [0.7, 0.2]]
    for tps in (authors_tps(src, dst, (640, 480)), fit_tps(src, dst, normalisation="size", size=(640, 480))):
        np.testing.assert_allclose(tps(src), dst, atol=1e-6)
    for collinear in (np.array([[300.0, 200.0], [310.0, 200.0], [320.0, 200.0], [330.0, 200.0]]),
                      np.array([[0.0, 0.0], [300.0, 200.0], [600.0, 400.0], [150.0, 100.0]])):
        with pytest.raises(ValueError, match="collinear or repeated"):
            authors_tps(collinear, collinear + 1.0, (640, 480))


def test_a_batch_member_from_a_small_cluster_spans_the_plane():
    """`solve_batch` works in coordinates normalised over all matches (tracking's RANSAC and refit):
    control points in a 15 px square of a 640 px spread were called "collinear" (ok False, absolute
    threshold on det of the scatter), so a compact object's 40 exact inliers gave "fit failed"."""
    from geofeat.apps.tracking import refit_on_inliers
    from geofeat.tps import normalise_points

    rng = np.random.default_rng(0)
    cluster = rng.uniform(300, 315, (40, 2))
    moved = cluster + [5.0, -3.0] + 0.002 * (cluster - 300) ** 2
    _, everything = normalise_points(np.vstack([cluster, rng.uniform(0, 640, (200, 2))]))
    s = everything[None, :40]
    d = s + 0.01 * rng.normal(size=s.shape)
    for scale in (1.0, 100.0):  # the verdict and the interpolation do not depend on the size
        w, a, ok = solve_batch(s * scale, d * scale, 0.0)
        assert ok[0]
        np.testing.assert_allclose(evaluate_batch(s[0] * scale, s * scale, w, a)[0], d[0] * scale, atol=1e-6 * scale)
    line = np.stack([np.linspace(0, 0.01, 10), 2 * np.linspace(0, 0.01, 10)], axis=-1)[None]
    assert not solve_batch(line, line, 1e-3)[2][0]  # a small collinear set is still refused
    src = np.vstack([cluster, rng.uniform(0, 640, (200, 2))])
    dst = np.vstack([moved, rng.uniform(0, 640, (200, 2))])
    start = np.arange(len(src)) < 40
    fit = refit_on_inliers(src, dst, start)
    assert fit.warp is not None and fit.inliers[:40].all() and not fit.inliers[40:].any()


def test_an_image_size_with_hartleys_normalisation_is_refused():
    """`size` belongs to the authors' normalisation; given with Hartley's (the default) it was ignored,
    so a caller who meant the authors' spline got another one without a word."""
    from geofeat.tps import fit_tps

    rng = np.random.default_rng(0)
    src = rng.uniform(0, 600, (12, 2))
    dst = src + rng.normal(0, 2, src.shape)
    with pytest.raises(ValueError, match="size"):
        fit_tps(src, dst, size=(640, 480))
    a = fit_tps(src, dst, normalisation="size", size=(640, 480))
    b = fit_tps(src, dst)
    np.testing.assert_allclose(a(src), dst, atol=1e-6)
    np.testing.assert_allclose(b(src), dst, atol=1e-6)
