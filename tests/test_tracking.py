"""Tracking: TPS + RANSAC on synthetic matches, similarity measures, and a short simulated sequence."""

import csv
from pathlib import Path

import numpy as np
import pytest

from geofeat.apps.localfit import locally_consistent
from geofeat.apps.tracking import (
    check_roi, default_roi, fit_tps_local, fit_tps_ransac, ncc, roi_grid, ssim, track_sequence, write_tracking,
)
from geofeat.tps import fit_tps, normalise_points


def smooth_warp(p: np.ndarray) -> np.ndarray:
    """A smooth non-affine warp of 640 x 480 pixels (bending of up to ~12 px on top of an affine map)."""
    x, y = p[:, 0], p[:, 1]
    return np.stack([30 + 1.1 * x + 0.1 * y + 12 * np.sin(y / 80), 20 - 0.08 * x + 0.95 * y + 10 * np.cos(x / 90)], 1)


def matches_with_outliers(n: int, outlier_fraction: float, seed: int):
    rng = np.random.default_rng(seed)
    src = rng.uniform([40, 40], [600, 440], (n, 2))
    dst = smooth_warp(src) + rng.normal(0, 0.2, (n, 2))
    outlier = rng.permutation(n) < int(outlier_fraction * n)
    dst[outlier] = rng.uniform([0, 0], [700, 500], (outlier.sum(), 2))
    return src, dst, outlier


@pytest.mark.parametrize("seed", [0, 1])
def test_tps_ransac_recovers_a_smooth_warp_with_half_outliers(seed):
    src, dst, outlier = matches_with_outliers(300, 0.5, seed)
    fit = fit_tps_ransac(src, dst, seed=seed)
    assert fit.ok
    # the outliers are rejected, (nearly) all inliers kept
    assert (fit.inliers & outlier).sum() <= 2
    assert (fit.inliers & ~outlier).sum() >= 0.95 * (~outlier).sum()
    # sub-pixel on the inliers, against the true (noise-free) warp
    err = np.linalg.norm(fit.warp(src[~outlier]) - smooth_warp(src[~outlier]), axis=1)
    assert np.median(err) < 0.5 and np.percentile(err, 95) < 1.0


def test_repeated_matches_count_once_in_the_robust_fits():
    """fit_tps_ransac and refit_on_inliers counted each copy of a repeated match (the same template and
    frame pixels, as SIFT's copies of one keypoint with another orientation give) as an inlier: five
    matches repeated three times passed min_inliers=10, a spline through five points reported as a
    successful fit, and a repeated wrong cluster outvoted the right matches. The local fit already
    counted them once."""
    from geofeat.apps.tracking import refit_on_inliers

    rng = np.random.default_rng(0)
    five = rng.uniform([40, 40], [600, 440], (5, 2))
    outliers = rng.uniform([0, 0], [640, 480], (30, 2))
    src = np.vstack([np.repeat(five, 3, axis=0), rng.uniform([0, 0], [640, 480], (30, 2))])
    dst = np.vstack([np.repeat(smooth_warp(five), 3, axis=0), outliers])
    fit = fit_tps_ransac(src, dst)
    assert not fit.ok and not fit.inliers.any()
    refit = refit_on_inliers(src, dst, np.arange(len(src)) < 15)
    assert not refit.ok and not refit.inliers.any()
    # each copy gets its distinct match's verdict: the fit is the one without the copies
    src = rng.uniform([40, 40], [600, 440], (60, 2))
    dst = smooth_warp(src)
    dst[40:] = rng.uniform([0, 0], [640, 480], (20, 2))
    alone = fit_tps_ransac(src, dst)
    copies = fit_tps_ransac(np.vstack([src, src[::3]]), np.vstack([dst, dst[::3]]))
    assert alone.ok and copies.ok
    np.testing.assert_array_equal(copies.inliers, np.concatenate([alone.inliers, alone.inliers[::3]]))
    np.testing.assert_allclose(copies.warp(src), alone.warp(src))


def crumple_warp(p: np.ndarray) -> np.ndarray:
    """A cloth shrunk to 0.55x and rippled (14 px waves, 250 px long) in both directions: smooth, but
    no thin-plate spline through 4 matches explains more than a small part of it."""
    x, y = p[:, 0], p[:, 1]
    return np.stack([150 + 0.55 * x + 14 * np.sin(y / 40), 100 + 0.55 * y + 14 * np.sin(x / 40)], 1)


@pytest.mark.parametrize("seed", [0, 1])
def test_local_fit_keeps_the_matches_of_a_crumpled_surface_that_global_ransac_loses(seed):
    rng = np.random.default_rng(seed)
    src = rng.uniform([40, 40], [600, 440], (600, 2))
    dst = crumple_warp(src) + rng.normal(0, 0.3, (600, 2))
    outlier = rng.permutation(600) < 300
    dst[outlier] = rng.uniform([100, 50], [550, 400], (300, 2))  # wrong matches land on the same region
    grid = np.stack(np.meshgrid(np.linspace(60, 580, 10), np.linspace(60, 420, 10)), -1).reshape(-1, 2)
    local, ransac = fit_tps_local(src, dst, seed=seed), fit_tps_ransac(src, dst, seed=seed)
    assert local.ok
    assert (local.inliers & ~outlier).sum() >= 0.85 * 300 and (local.inliers & outlier).sum() <= 2
    local_error = np.median(np.linalg.norm(local.warp(grid) - crumple_warp(grid), axis=1))
    assert local_error < 1.5
    # the global model keeps a fraction of the correct matches and misplaces the grid
    assert (ransac.inliers & ~outlier).sum() < 0.5 * (local.inliers & ~outlier).sum()
    assert not ransac.ok or np.median(np.linalg.norm(ransac.warp(grid) - crumple_warp(grid), axis=1)) > 5 * local_error


def test_the_track_threshold_reaches_the_local_consistency_step(monkeypatch):
    """`geofeat track --threshold` says it is the inlier threshold of both fits, but the local
    consistency step kept its fixed 4 px: a user's 10 px still dropped every match 4 px off its
    neighbours' affine map. The tolerance now scales with it (4 px at the default 3 px)."""
    from geofeat.apps import localfit

    seen, consistent = [], localfit.locally_consistent

    def spy(src, dst, *args, **kwargs):
        seen.append(kwargs["tolerance_px"])
        return consistent(src, dst, *args, **kwargs)

    monkeypatch.setattr(localfit, "locally_consistent", spy)
    rng = np.random.default_rng(0)
    src = rng.uniform([40, 40], [600, 440], (200, 2))
    dst = crumple_warp(src) + rng.normal(0, 0.3, (200, 2))
    default, loose = fit_tps_local(src, dst), fit_tps_local(src, dst, threshold_px=7.5)
    assert seen == [pytest.approx(4.0), pytest.approx(10.0)]
    assert default.ok and loose.ok


def test_local_consistency_rejects_random_matches_and_checks_its_input():
    rng = np.random.default_rng(3)
    src, dst = rng.uniform(0, 640, (500, 2)), rng.uniform(0, 640, (500, 2))
    assert locally_consistent(src, dst).sum() <= 5
    assert not fit_tps_local(src, dst).ok
    assert not locally_consistent(src[:7], src[:7] + 1).any()  # too few matches to vote
    assert locally_consistent(src[:40], src[:40] * 0.5 + 3).all()  # an affine map: every match agrees
    with pytest.raises(ValueError, match="shapes"):
        locally_consistent(src, dst[:10])
    with pytest.raises(ValueError, match="finite"):
        locally_consistent(np.where(np.arange(500)[:, None] == 3, np.nan, src), dst)


def test_repeated_matches_vote_once():
    """A match repeated at one template position (SIFT emits a keypoint once per dominant orientation,
    and the copies often match the same frame point) is one piece of evidence: three wrong matches,
    each repeated three times, must not confirm each other as nine neighbours would."""
    rng = np.random.default_rng(5)
    src = rng.uniform(0, 640, (300, 2))
    dst = src * 0.9 + [20, 10] + rng.normal(0, 0.3, (300, 2))  # correct matches: one affine map
    centre = src[np.argmin(np.linalg.norm(src - [320, 240], axis=1))]
    wrong_src = centre + np.array([[0.5, 0.5], [4.0, 0.5], [0.5, 4.0]])  # among the correct ones' neighbours
    wrong_dst = wrong_src * [-1, 1] + [700, 40]  # a mirror: agrees with itself, not with the others
    alone = locally_consistent(np.vstack([src, wrong_src]), np.vstack([dst, wrong_dst]))
    assert not alone[-3:].any()  # three wrong matches are outvoted by their correct neighbours
    repeated_src, repeated_dst = np.repeat(wrong_src, 3, axis=0), np.repeat(wrong_dst, 3, axis=0)
    confirmed = locally_consistent(np.vstack([src, repeated_src]), np.vstack([dst, repeated_dst]))
    assert not confirmed[-9:].any()
    assert (confirmed[:300] == alone[:300]).mean() > 0.95  # the correct matches are judged as before


def test_a_match_never_votes_for_itself_when_template_pixels_repeat():
    """Two matches from one template pixel (SIFT copies of a keypoint matched to different frame points)
    tie at distance 0 in the neighbour search, so a match was sometimes its own neighbour (and its copy
    left out): hypotheses through the match itself carried it exactly, and random matches with shared
    template pixels were confirmed (402 of 2400 here; 0 without the repetition)."""
    confirmed = 0
    for s in range(100):
        rng = np.random.default_rng(s)
        src = rng.uniform(0, 320, (12, 2))
        src[6:] = src[:6]  # each template pixel twice, each copy matched to its own random frame pixel
        confirmed += int(locally_consistent(src, rng.uniform(0, 240, (12, 2)), seed=s).sum())
    assert confirmed <= 3  # chance alone (a random affine map through 3 neighbours carrying the match)


def test_local_consistency_checks_its_settings():
    """neighbours < 3 or trials < 1 were numpy errors from inside the vote (LinAlgError, argmax of an
    empty sequence); a NaN or negative tolerance silently confirmed no match at all."""
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 640, (40, 2))
    dst = src * 0.5 + 3
    assert locally_consistent(src, dst, neighbours=3).all()
    for kwargs, name in (({"neighbours": 2}, "neighbours"), ({"neighbours": 0}, "neighbours"),
                         ({"trials": 0}, "trials"), ({"tolerance_px": float("nan")}, "tolerance_px"),
                         ({"tolerance_px": -1.0}, "tolerance_px")):
        with pytest.raises(ValueError, match=name):
            locally_consistent(src, dst, **kwargs)


def test_refit_fails_when_its_last_fit_keeps_too_few_inliers():
    """`refit_on_inliers` (and so `fit_tps_ransac` / `fit_tps_local`) returned a warp with fewer than
    `min_inliers` inliers when the refit on a bad start lost them (the count checked was the start's);
    a NaN threshold made `fit_tps_local` return ok with no inlier at all; a start of another length
    was a numpy broadcasting error."""
    from geofeat.apps.tracking import refit_on_inliers

    rng = np.random.default_rng(1)
    src, dst = rng.uniform(0, 200, (40, 2)), rng.uniform(0, 200, (40, 2))  # no warp explains them
    for _ in range(10):
        start = np.zeros(40, bool)
        start[rng.choice(40, 12, replace=False)] = True
        r = refit_on_inliers(src, dst, start, min_inliers=10)
        assert not r.ok or r.inliers.sum() >= 10
    src, dst = matches_with_outliers(200, 0.3, 0)[:2]
    with pytest.raises(ValueError, match="threshold_px"):
        fit_tps_local(src, dst, threshold_px=float("nan"))
    with pytest.raises(ValueError, match="start"):
        refit_on_inliers(src, dst, np.ones(10, bool))


def test_tps_interpolates_and_normalisation_is_hartleys():
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 500, (20, 2))
    dst = smooth_warp(src)
    warp = fit_tps(src, dst, regularisation=0.0)
    np.testing.assert_allclose(warp(src), dst, atol=1e-6)
    T, p = normalise_points(src)
    np.testing.assert_allclose(p.mean(axis=0), 0, atol=1e-9)
    assert np.isclose(np.linalg.norm(p, axis=1).mean(), np.sqrt(2))
    np.testing.assert_allclose(p, src @ T[:2, :2].T + T[:2, 2])


def test_affine_warp_is_reproduced_exactly():
    rng = np.random.default_rng(4)
    src = rng.uniform(0, 400, (50, 2))
    A = np.array([[0.9, -0.3, 40], [0.25, 1.05, -12]])
    dst = src @ A[:, :2].T + A[:, 2]
    fit = fit_tps_ransac(src, dst)
    test = rng.uniform(0, 400, (100, 2))
    np.testing.assert_allclose(fit.warp(test), test @ A[:, :2].T + A[:, 2], atol=1e-3)


def test_ransac_fails_cleanly_on_pure_noise_and_too_few_matches():
    rng = np.random.default_rng(5)
    fit = fit_tps_ransac(rng.uniform(0, 640, (200, 2)), rng.uniform(0, 640, (200, 2)), threshold_px=1.0)
    assert not fit.ok and fit.warp is None
    assert not fit_tps_ransac(np.zeros((5, 2)), np.zeros((5, 2))).ok
    with pytest.raises(ValueError, match="src, dst"):
        fit_tps_ransac(np.zeros((5, 2)), np.zeros((6, 2)))
    with pytest.raises(ValueError, match="collinear"):
        fit_tps(np.c_[np.arange(5.0), np.arange(5.0)], np.zeros((5, 2)))


def test_similarity_measures():
    rng = np.random.default_rng(6)
    a = rng.random((40, 50)).astype(np.float32)
    assert np.isclose(ncc(a, a), 1.0) and np.isclose(ncc(a, 1 - a), -1.0)
    assert np.isclose(ncc(a, 0.5 * a + 0.2), 1.0)  # invariant to gain and offset
    assert np.isclose(ssim(a, a), 1.0)
    assert ssim(a, rng.random((40, 50)).astype(np.float32)) < 0.2


def test_ncc_reads_its_mask_as_bool_and_checks_shapes():
    """A 0/1 integer mask indexed rows 0 and 1 instead of selecting pixels (ssim already read it as
    bool); images of different shapes were a numpy IndexError."""
    rng = np.random.default_rng(7)
    a, b = rng.random((20, 20)), rng.random((20, 20))
    mask = np.zeros((20, 20), np.uint8)
    mask[5:15, 5:15] = 1
    assert ncc(a, b, mask) == ncc(a, b, mask.astype(bool)) == ncc(a[5:15, 5:15], b[5:15, 5:15])
    assert np.isnan(ncc(a, b, np.zeros((20, 20), bool))) and np.isnan(ncc(np.ones((5, 5)), np.ones((5, 5))))
    for x, y, m in ((a, b[:10], None), (a, b, mask[:10])):
        with pytest.raises(ValueError, match="one shape"):
            ncc(x, y, m)


def test_refit_without_smoothing_on_a_repeated_point_fails_cleanly():
    """With regularisation 0 a template point matched twice (SIFT repeats a location with two
    orientations) made the refit's linear system singular: a LinAlgError out of `fit_tps_ransac`
    instead of a failed fit."""
    from geofeat.apps.tracking import refit_on_inliers

    rng = np.random.default_rng(8)
    src = rng.uniform(0, 200, (60, 2))
    src = np.vstack([src, src[:5]])
    dst = 1.1 * src + 3
    dst[60:] += 0.5  # matched to a second frame point half a pixel away: no interpolating spline
    assert not refit_on_inliers(src, dst, np.ones(65, bool), regularisation=0.0).ok
    assert not fit_tps_ransac(src, dst, regularisation=0.0).ok
    assert fit_tps_ransac(src, dst).ok  # the default smoothing fits it
    # an exact copy of a match (the same frame point too) counts once, and the spline through the others fits
    same = 1.1 * src + 3
    assert refit_on_inliers(src, same, np.ones(65, bool), regularisation=0.0).ok
    assert fit_tps_ransac(src, same, regularisation=0.0).ok


def test_roi_helpers():
    mask = np.zeros((100, 200), bool)
    mask[20:81, 40:141] = True
    assert default_roi(mask) == (45, 23, 135, 77)
    g = roi_grid((0, 0, 90, 45))
    assert g.shape == (100, 2) and g[0].tolist() == [0, 0] and g[-1].tolist() == [90, 45]
    with pytest.raises(ValueError, match="roi"):
        check_roi((10, 10, 300, 50), (100, 200))
    with pytest.raises(ValueError, match="roi"):
        check_roi("a,b", (100, 200))
    with pytest.raises(ValueError, match="roi"):  # was an OverflowError
        check_roi((0, 0, float("inf"), 50), (100, 200))
    for shrink in (1.5, 1.0, -0.5, float("nan")):  # 1.5 gave x0 > x1, -0.5 a box off the mask's
        with pytest.raises(ValueError, match="shrink"):
            default_roi(mask, shrink)
    with pytest.raises(ValueError, match="mask"):  # was "not enough values to unpack"
        default_roi(mask[0])


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    from geofeat.sim import simulate_sequence

    return simulate_sequence(tmp_path_factory.mktemp("track") / "cloth", scenario="deform", n_frames=3, seed=21,
                             width=320, height=240, progress=False)


def test_visible_grid_error_scores_true_positions_zero_and_a_shift_by_its_length(sequence):
    from geofeat.apps.tracking import _visible_grid_error
    from geofeat.groundtruth.sources import GroundTruth
    from geofeat.io import read_sequence

    seq = read_sequence(sequence)
    truth = GroundTruth(seq, None)
    grid = roi_grid((100, 70, 220, 170))
    target = seq.targets[-1]
    xy, visible = truth.project(target, grid)
    assert visible.mean() > 0.5
    error, fraction = _visible_grid_error(truth.project(target, grid), xy)
    assert error == pytest.approx(0.0, abs=1e-9) and fraction == pytest.approx(visible.mean())
    assert _visible_grid_error((xy, visible), xy + [3.0, 4.0])[0] == pytest.approx(5.0)
    # the reference frame maps onto itself
    same, seen = truth.project(seq.reference, grid)
    np.testing.assert_allclose(same[seen], grid[seen], atol=0.05)


def test_grid_error_leaves_out_grid_points_off_the_object_in_the_reference(sequence):
    """An ROI corner on the background has no true position: a warp that carried it onto the cloth was
    scored against whichever part of the cloth it reached (here the median of the grid error was that
    of these meaningless points), while the points on the object were tracked exactly."""
    from geofeat.apps.objectmask import object_mask
    from geofeat.apps.tracking import _grid_error
    from geofeat.groundtruth.sources import GroundTruth
    from geofeat.io import read_sequence

    seq = read_sequence(sequence)
    truth = GroundTruth(seq, None)
    target = seq.targets[-1]
    mask = object_mask(seq, seq.reference)[0]
    ys, xs = np.nonzero(mask)
    on = np.stack([xs, ys], 1)[np.random.default_rng(0).choice(len(xs), 200, replace=False)].astype(float)
    xy, visible = truth.project(target, on)
    on, xy = on[visible][:4], xy[visible][:4]  # four grid points on the cloth, tracked exactly
    ys, xs = np.nonzero(~mask)
    off = np.stack([xs, ys], 1)[:6].astype(float)  # six on the background
    assert not truth.reference_keep(off).any() and truth.reference_keep(on).all()
    grid = np.vstack([on, off])
    tracked = np.vstack([xy, np.repeat(xy[:1], 6, axis=0)])  # the background points put onto the cloth
    assert _grid_error(truth, target, tracked, grid) < 0.5


def test_track_simulated_sequence_outputs(sequence, tmp_path):
    import imageio.v2 as imageio

    csv_path, table = write_tracking([sequence], tmp_path, ("sift", "orb"), n_keypoints=500, progress=False)
    lines = csv_path.read_text().splitlines()
    assert len(lines) == 1 + 2 * 2  # header + 2 descriptors x 2 target frames
    grid = np.load(tmp_path / "cloth" / "sift" / "grid.npz")
    assert grid["reference_points"].shape == (100, 2) and grid["points"].shape == (3, 100, 2)
    np.testing.assert_array_equal(grid["points"][0], grid["reference_points"])
    assert len(imageio.mimread(tmp_path / "cloth" / "sift" / "track.gif")) == 3
    md = (tmp_path / "tracking.md").read_text()
    assert "| sift |" in md and "object mask from simulator" in md
    assert "depth profile clean" in md  # the simulator's geofeat.json profile, which describe used
    assert "Table IV" not in md  # neither SIFT nor ORB is in the paper's tracking table
    # SIFT tracks a gently deforming cloth: the tracked grid is a few pixels from the truth
    import csv

    rows = [r for r in csv.DictReader(open(csv_path)) if r["descriptor"] == "sift"]
    assert all(r["failed"] == "False" for r in rows)
    assert max(float(r["grid_error_px"]) for r in rows) < 5.0
    assert min(float(r["ssim"]) for r in rows) > 0.3
    # the kept matches are mostly correct under the bench's ground truth; MS counts them over the keypoints
    assert min(float(r["precision"]) for r in rows) > 0.8
    assert all(0 < float(r["ms"]) <= float(r["inliers"]) / min(int(r["n_template"]), int(r["n_frame"])) + 1e-9
               for r in rows)


def test_track_bad_input(sequence, tmp_path):
    with pytest.raises(ValueError, match="descriptor"):
        track_sequence(sequence, ("nope",), progress=False)
    with pytest.raises(ValueError, match="roi"):
        track_sequence(sequence, ("sift",), roi=(0, 0, 1000, 10), progress=False)
    with pytest.raises(ValueError, match="keypoints"):
        track_sequence(sequence, ("sift",), roi=(0, 0, 3, 3), progress=False)
    single = tmp_path / "single"
    single.mkdir()
    for f in sequence.iterdir():
        if f.name.startswith("frame-000-master") or f.name in ("intrinsics.xml", "groundtruth.json"):
            (single / f.name).write_bytes(f.read_bytes())
    with pytest.raises(ValueError, match="reference frame and at least one other"):
        track_sequence(single, ("sift",), progress=False)


def test_track_command(sequence, tmp_path, capsys):
    from geofeat.cli import main

    assert main(["track", str(sequence), "--descriptors", "sift", "--keypoints", "400", "--out", str(tmp_path)]) == 0
    assert "| sift |" in capsys.readouterr().out
    assert (tmp_path / "track.csv").is_file() and (tmp_path / "cloth" / "sift" / "track.gif").is_file()
    assert main(["track", str(sequence), "--descriptors", "sift", "--roi", "1,2,3", "--out", str(tmp_path)]) == 2
    assert "--roi" in capsys.readouterr().err
    assert main(["track", str(sequence), "--descriptors", "bogus", "--out", str(tmp_path)]) == 2


def test_refinement_never_worse_than_the_spline_on_an_easy_pair(sequence):
    res = track_sequence(sequence, ("sift",), n_keypoints=500, progress=False, refine="photometric")
    rows = res["sift"].rows
    assert all(not r["failed"] for r in rows) and any(r["refined"] for r in rows)
    for r in rows:  # gentle deformation: the spline is already sub-pixel; refinement must not lose it
        assert r["grid_error_px"] <= r["grid_error_tps_px"] + 0.05, r
        assert r["grid_error_px"] < 1.0 and r["ssim"] > 0.8
    with pytest.raises(ValueError, match="refine"):
        track_sequence(sequence, ("sift",), progress=False, refine="bogus")


@pytest.fixture(scope="module")
def folded(tmp_path_factory):
    """The reference and frame 2 of a 5-frame simulated sequence with strong folds (hard preset; seed and
    frame chosen among seeds 0-5 and frames 2-4 where SIFT's spline is more than 3 px off and not lost:
    4.0 px, refined to 0.8, when the simulator got finer sub-steps for short sequences)."""
    from geofeat.sim import simulate_sequence

    root = tmp_path_factory.mktemp("fold")
    full = simulate_sequence(root / "full", scenario="deform", preset="hard", n_frames=5, seed=2, width=320,
                             height=240, progress=False)
    pair = root / "fold"
    pair.mkdir()
    for f in full.iterdir():
        if f.name.startswith(("frame-000-master", "frame-002")) or not f.name.startswith("frame-"):
            (pair / f.name).write_bytes(f.read_bytes())
    return pair


def test_refinement_follows_a_fold_the_spline_misses(folded):
    res = track_sequence(folded, ("sift",), progress=False, refine="photometric")
    r = res["sift"].rows[-1]  # strong folds: sparse matches and one spline leave pixels of error
    assert r["grid_error_tps_px"] > 3.0 and r["refined"], r
    assert r["grid_error_px"] < 0.5 * r["grid_error_tps_px"], r
    # the grid written out is the refined one, not the spline's
    none = track_sequence(folded, ("sift",), progress=False, refine="none")["sift"]
    assert np.abs(res["sift"].points[-1] - none.points[-1]).max() > 1.0
    assert none.rows[-1]["grid_error_px"] == pytest.approx(r["grid_error_tps_px"])


def test_track_with_geokey_keypoints(sequence, tmp_path, capsys):
    from geofeat.cli import main

    assert main(["track", str(sequence), "--descriptors", "geobit", "--keypoints", "500", "--detector", "geokey",
                 "--refine", "none", "--out", str(tmp_path)]) == 0
    md = (tmp_path / "tracking.md").read_text()
    assert "detector: geobit: geokey" in md
    assert "| geobit (paper) | 0.46 | 0.42 | 0.27 |" in md  # the paper's Table IV beside ours
    import csv

    rows = list(csv.DictReader(open(tmp_path / "track.csv")))
    # GeoKey's keypoints, described by GeoBit, track a gently deforming cloth within a few pixels
    assert rows and all(r["failed"] == "False" for r in rows)
    assert max(float(r["grid_error_px"]) for r in rows) < 5.0


def test_each_descriptor_is_tracked_on_its_own_detector_by_default(sequence, tmp_path):
    """Without --detector, GeoBit tracks GeoKey's keypoints and ORB SIFT's (the template keypoints
    differ); --detector names one for both."""
    import csv

    from geofeat.cli import main

    args = ["track", str(sequence), "--descriptors", "geobit,orb", "--keypoints", "300", "--refine", "none"]
    assert main(args + ["--out", str(tmp_path / "own")]) == 0
    assert "detector: geobit: geokey, orb: sift" in (tmp_path / "own" / "tracking.md").read_text()
    rows = list(csv.DictReader(open(tmp_path / "own" / "track.csv")))
    assert [r["descriptor"] for r in rows] == ["geobit", "geobit", "orb", "orb"]  # the order asked for
    template = {r["descriptor"]: r["n_template"] for r in rows}
    assert template["geobit"] != template["orb"]
    assert main(args + ["--detector", "sift", "--out", str(tmp_path / "named")]) == 0
    assert "detector: geobit: sift, orb: sift" in (tmp_path / "named" / "tracking.md").read_text()
    rows = list(csv.DictReader(open(tmp_path / "named" / "track.csv")))
    assert len({r["n_template"] for r in rows}) == 1


def test_guided_matches_follow_the_prediction_among_identical_descriptors():
    """Repeated texture: two frame keypoints carry the template keypoint's exact descriptor; the one
    near the predicted position is chosen, a keypoint without prediction is not matched, and each
    frame keypoint is taken by at most one (the descriptor-nearest) template keypoint."""
    from geofeat.features import Features
    from geofeat.apps.tracking import guided_matches

    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 8)).astype(np.float32)
    f0 = Features(np.array([[0.0, 0.0], [5.0, 5.0], [9.0, 9.0]]), np.stack([a, b, b + 0.1]), np.ones(3, bool))
    f1 = Features(np.array([[10.0, 10.0], [200.0, 200.0], [60.0, 60.0]]), np.stack([a, a, b]), np.ones(3, bool))
    predicted = np.array([[195.0, 205.0], [55.0, 58.0], [62.0, 61.0]])
    assert guided_matches(f0, f1, predicted, radius=40.0).tolist() == [1, 2, -1]  # 2 loses keypoint 2 to 1
    predicted[0] = np.nan
    assert guided_matches(f0, f1, predicted, radius=40.0)[0] == -1
    assert guided_matches(f0, f1, predicted + 100.0, radius=40.0).tolist() == [-1, -1, -1]  # nothing near



def test_guided_matches_check_their_input():
    """Predictions of another shape were scipy / numpy errors; a negative radius searched as its
    absolute value and a NaN one matched nothing; float template descriptors against uint8 frame ones
    were compared as L2 numbers."""
    from geofeat.features import Features
    from geofeat.apps.tracking import guided_matches

    rng = np.random.default_rng(0)
    kp = rng.uniform(0, 100, (6, 2))
    f0 = Features(kp, rng.normal(size=(6, 8)).astype(np.float32), np.ones(6, bool))
    bits = Features(kp, rng.integers(0, 256, (6, 8), dtype=np.uint8), np.ones(6, bool))
    assert guided_matches(f0, f0, kp).tolist() == list(range(6))
    for predicted in (kp[:3], kp.ravel(), np.c_[kp, kp[:, :1]]):
        with pytest.raises(ValueError, match="predicted0"):
            guided_matches(f0, f0, predicted)
    for radius in (-40.0, float("nan"), 0.0):
        with pytest.raises(ValueError, match="radius"):
            guided_matches(f0, f0, kp, radius=radius)
    with pytest.raises(ValueError, match="different kinds"):
        guided_matches(f0, bits, kp)
    nan = Features(kp, f0.descriptors.copy(), np.ones(6, bool))
    nan.descriptors[2, 0] = np.nan  # np.argmin takes a NaN distance for the smallest: a wrong match
    with pytest.raises(ValueError, match=r"features1 has NaN.*\[2\]"):
        guided_matches(f0, nan, kp)
    nan.valid[2] = False  # an invalid keypoint's descriptor is never compared
    assert guided_matches(f0, nan, kp).tolist() == [0, 1, -1, 3, 4, 5]


def test_paper_table_iv_rows_follow_the_descriptors_tracked():
    from geofeat.apps.tracking import paper_table_iv

    text = paper_table_iv(["geopatch", "sift", "tfeat-sim"])
    assert "| geopatch (paper) | 0.49 | 0.45 | 0.29 |" in text and "| tfeat-sim (paper) | 0.31 | 0.37 | 0.29 |" in text
    assert "sift (paper)" not in text
    assert paper_table_iv(["sift", "orb"]) == ""


def test_tracking_table_counts_a_failed_frame_as_lost_not_as_missing():
    from geofeat.apps.tracking import TRACK_COLUMNS, tracking_table

    def row(descriptor, error, failed=False):
        r = {c: "nan" for c in TRACK_COLUMNS}
        r.update(sequence="s", descriptor=descriptor, frame="f", failed=str(failed), grid_error_px=str(error),
                 grid_error_visible_px=str(error))
        return r

    rows = [row("fails", 0.5), row("fails", 0.5), row("fails", "nan", failed=True),
            row("poor", 0.5), row("poor", 30.0), row("poor", 30.0),
            row("lost", 0.5), row("lost", "nan", True), row("lost", "nan", True)]
    table = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[1:-1]] for line in tracking_table(rows).splitlines()[2:]}
    # median of (0.5, 0.5, lost) = 0.5; of (0.5, 30, 30) = 30; two frames of three lost: the sequence is lost
    assert table["fails"][6:9] == ["0.5", "0.5", "1/3"]
    assert table["poor"][6:8] == ["30.0", "30.0"]
    assert table["lost"][6:8] == ["lost", "lost"]
    from geofeat.apps.tracking import sequence_error_table

    per_sequence = sequence_error_table(rows + [dict(row("poor", 2.0), sequence="t")]).splitlines()
    assert per_sequence[0] == "| sequence | fails | poor | lost |"
    assert per_sequence[2] == "| s | 0.50 | 30.00 | lost |" and per_sequence[3] == "| t | – | 2.00 | – |"
    assert sequence_error_table([row("x", "nan")]) == ""  # no simulator truth: no table


def test_ransac_arguments_are_checked_before_any_work():
    src, dst, _ = matches_with_outliers(40, 0.2, seed=0)
    with pytest.raises(TypeError, match="sample_size: expected an integer"):  # "slice indices must be integers"
        fit_tps_ransac(src, dst, sample_size=5.5)
    with pytest.raises(TypeError, match="iterations: expected an integer"):
        fit_tps_ransac(src, dst, iterations=100.5)
    with pytest.raises(ValueError, match="regularisation: expected a number >= 0"):  # was used as given
        fit_tps_ransac(src, dst, regularisation=-1.0)
    # a numpy threshold is a number (was "threshold_px: expected a positive number, got np.float32(3.0)")
    assert fit_tps_ransac(src, dst, threshold_px=np.float32(3.0)).warp is not None


def test_a_descriptor_named_twice_is_refused(sequence, tmp_path):
    """`--descriptors sift,sift` wrote every sift row twice into track.csv, and tracking.md counted
    each frame twice (failed frames "0/4" for 2 target frames); as in bench, it is refused."""
    with pytest.raises(ValueError, match="'sift' is named twice"):
        write_tracking([sequence], tmp_path / "t", ("sift", "SIFT"), n_keypoints=300, progress=False, refine="none")
    assert not (tmp_path / "t").exists()


def test_two_weights_whose_result_folders_would_be_one_are_refused(sequence, tmp_path, monkeypatch):
    """"geopatch=a/w.pt" and "geopatch=a_w.pt" both wrote OUT/<sequence>/geopatch_a_w.pt/: the second's
    grid.npz and track.gif replaced the first's without a word. Refused before any work."""
    import shutil

    import geofeat

    shipped = Path(geofeat.__file__).parent / "data" / "geopatch.pt"
    (tmp_path / "a").mkdir()
    shutil.copy(shipped, tmp_path / "a" / "w.pt")
    shutil.copy(shipped, tmp_path / "a_w.pt")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="would write their results into one folder, 'geopatch_a_w.pt'"):
        write_tracking([sequence], tmp_path / "t", ("geopatch=a/w.pt", "geopatch=a_w.pt"), n_keypoints=300,
                       progress=False, refine="none")
    assert not (tmp_path / "t").exists()


def _public_copy(sequence, out, identical: str):
    """`sequence` in the public layout only (no simulator ground truth), frame `identical` replaced by
    a copy of the reference frame."""
    out.mkdir()
    for f in sequence.iterdir():
        if f.name.endswith("-gt.npz") or f.name == "groundtruth.json":
            continue
        (out / f.name).write_bytes(f.read_bytes())
    for suffix in ("-rgb.png", "-depth.png", ".csv"):
        (out / f"{identical}{suffix}").write_bytes((sequence / f"frame-000-master{suffix}").read_bytes())
    return out


def test_a_frame_identical_to_the_reference_scores_zero_error_and_full_precision(sequence, tmp_path):
    # ground truth from the csv landmarks covers only their convex hull: a kept match there is not
    # "wrong", it is unscored; precision used to count it as wrong (0.77 on this identical frame)
    folder = _public_copy(sequence, tmp_path / "public", "frame-001")
    result = track_sequence(folder, ("sift",), n_keypoints=300, refine="none", progress=False)["sift"]
    row = next(r for r in result.rows if r["frame"] == "frame-001")
    assert not row["failed"] and row["inlier_rate"] == 1.0
    assert row["grid_error_px"] == pytest.approx(0.0, abs=1e-6)
    assert row["precision"] == pytest.approx(1.0)
    np.testing.assert_allclose(result.points[1], result.reference_points, atol=1e-6)


def test_a_skipped_frame_counts_as_lost_not_as_absent(sequence, tmp_path):
    """A frame that a descriptor's detector could not use (no depth: GeoKey finds nothing) had no row,
    so that descriptor's grid error and failed-frames count were taken over fewer frames than those of
    a descriptor whose fit on the frame failed and counted as lost (GeoBit '0.0, 0/1' beside SIFT
    'lost, 1/2' on one sequence)."""
    import cv2

    folder = _public_copy(sequence, tmp_path / "public", "frame-001")
    depth = cv2.imread(str(folder / "frame-002-depth.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(folder / "frame-002-depth.png"), np.zeros_like(depth))
    skipped = []
    _, table = write_tracking([folder], tmp_path / "out", ("sift",), n_keypoints=300, refine="none",
                              progress=False, skipped=skipped)
    assert skipped == ["public/frame-002"]
    rows = list(csv.DictReader(open(tmp_path / "out" / "track.csv")))
    assert [(r["frame"], r["failed"]) for r in rows] == [("frame-001", "False"), ("frame-002", "True")]
    sift = next(line for line in table.splitlines() if line.startswith("| sift |"))
    assert sift.endswith("| lost | – | 1/2 |"), table  # lost by the landmarks; no forward truth to be lost by
    assert sift.startswith("| sift | 0.50 |"), table  # no matches: inlier rate 0, as a failed fit without matches
    md = (tmp_path / "out" / "tracking.md").read_text()
    assert "SKIPPED frames: frame-002" in md
    # frames/s over the one frame tracked: the skipped frame was counted as a second tracked one
    assert "1 target frame tracked in " in md and "1 skipped frame not counted" in md, md
    # track.gif left the frame out, so the animation jumped without a word; now a dark placeholder holds its place
    import imageio.v2 as imageio

    gif = imageio.mimread(tmp_path / "out" / "public" / "sift" / "track.gif")
    assert len(gif) == 3 and gif[2].shape == gif[1].shape
    # a plain placeholder: its label (wrapped onto several lines on a frame this small) at the top, and
    # nothing but the dark background below it, where the tracked frame has its picture
    plain = (gif[2][:, :, :3] == 40).all(axis=(1, 2))
    below_label = slice(np.flatnonzero(~plain).max() + 1, None)
    assert gif[2].shape[0] - below_label.start >= gif[2].shape[0] // 8  # the label leaves room below it
    assert gif[1][below_label, :, :3].std() > 1


def test_a_failed_frame_is_lost_only_by_the_errors_its_sequence_measures():
    """A sequence without the simulator's forward truth has no visible-point error, yet one failed frame
    made its cell read "lost" as if it had been measured; a sequence whose every frame failed must
    still read "lost" (its failed rows carry inf where the truth exists)."""
    from geofeat.apps.tracking import TRACK_COLUMNS, sequence_error_table, tracking_table

    def row(sequence, error, visible, failed=False):
        r = {c: "nan" for c in TRACK_COLUMNS}
        r.update(sequence=sequence, descriptor="sift", frame="f", failed=str(failed), grid_error_px=str(error),
                 grid_error_visible_px=str(visible))
        return r

    landmarks_only = [row("s", 0.5, "nan"), row("s", 0.5, "nan"), row("s", "inf", "nan", failed=True)]
    cells = [c.strip() for c in tracking_table(landmarks_only).splitlines()[2].split("|")[1:-1]]
    assert cells[6:9] == ["0.5", "–", "1/3"]
    all_failed = [row("t", "inf", "inf", failed=True), row("t", "inf", "inf", failed=True)]
    cells = [c.strip() for c in tracking_table(all_failed).splitlines()[2].split("|")[1:-1]]
    assert cells[6:9] == ["lost", "lost", "2/2"]
    assert sequence_error_table(landmarks_only) == ""
    assert sequence_error_table(all_failed).splitlines()[2] == "| t | lost |"


def test_tracking_md_names_the_template_frame(sequence, tmp_path):
    """Without a `master`/`ref` frame name the first frame in sorted order is the template; tracking.md
    did not say which frame it tracked from."""
    folder = _public_copy(sequence, tmp_path / "public", "frame-002")
    for f in list(folder.glob("frame-000-master*")):
        f.rename(folder / f.name.replace("frame-000-master", "frame-000"))
    write_tracking([folder], tmp_path / "out", ("sift",), n_keypoints=300, refine="none", progress=False)
    assert "- public: template frame frame-000, ROI (" in (tmp_path / "out" / "tracking.md").read_text()


class _FakeClock:
    """`time.perf_counter` for the tracking module that moves only when a test says so: timing
    tests then check the arithmetic of the reported times, not the speed of the machine."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self) -> float:
        return self.now


def test_frames_per_second_leave_out_the_template_set_up(sequence, tmp_path, monkeypatch):
    """tracking.md's frames/s divided the target frames by a time that included the template's set-up
    (reading, detecting and describing the reference), which dominates it when there are few frames."""
    import re
    import types

    from geofeat.apps import tracking

    clock = _FakeClock()
    monkeypatch.setattr(tracking, "time", types.SimpleNamespace(perf_counter=clock.perf_counter))
    build = tracking._Template.build.__func__
    match_and_fit = tracking._match_and_fit

    def slow_build(cls, *args):
        clock.now += 3.0  # the template's set-up takes 3 s
        return build(cls, *args)

    def timed_fit(*args):
        clock.now += 0.25  # each target frame 0.25 s
        return match_and_fit(*args)

    monkeypatch.setattr(tracking._Template, "build", classmethod(slow_build))
    monkeypatch.setattr(tracking, "_match_and_fit", timed_fit)
    write_tracking([sequence], tmp_path, ("sift",), n_keypoints=300, refine="none", progress=False)
    md = (tmp_path / "tracking.md").read_text()
    found = re.search(r"2 target frames tracked in ([\d.]+) s: ([\d.]+) frames/s .*set-up, ([\d.]+) s, not counted", md)
    assert found, md
    tracked, rate, setup = map(float, found.groups())
    assert (tracked, rate, setup) == (0.5, 4.0, 3.0)


def test_a_slow_runs_frames_per_second_keeps_its_significant_figures(sequence, tmp_path, monkeypatch):
    """tracking.md printed frames/s with two decimals: a CPU run with refinement and three
    descriptors (hundreds of seconds per frame) read "0.00 frames/s", and 0.014 read "0.01"."""
    import re
    import types

    from geofeat.apps import tracking

    clock = _FakeClock()
    monkeypatch.setattr(tracking, "time", types.SimpleNamespace(perf_counter=clock.perf_counter))
    match_and_fit = tracking._match_and_fit

    def slow_fit(*args):
        clock.now += 250.0  # each target frame 250 s
        return match_and_fit(*args)

    monkeypatch.setattr(tracking, "_match_and_fit", slow_fit)
    write_tracking([sequence], tmp_path, ("sift",), n_keypoints=300, refine="none", progress=False)
    md = (tmp_path / "tracking.md").read_text()
    found = re.search(r"2 target frames tracked in ([\d.]+) s: ([\d.]+) frames/s", md)
    assert found, md
    assert float(found.group(1)) == 500.0 and float(found.group(2)) == 0.004, md


def test_every_sequences_template_roi_is_checked_before_any_tracking(sequence, tmp_path, monkeypatch):
    """One --roi for two sequences, the second of smaller frames: its ROI was checked only when its
    turn came, after the first sequence had been tracked, and the error threw those results away."""
    import cv2

    from geofeat.apps import tracking
    from geofeat.io import read_intrinsics, write_intrinsics

    first = _public_copy(sequence, tmp_path / "a", "frame-001")
    small = _public_copy(sequence, tmp_path / "b", "frame-001")
    for f in small.glob("*.csv"):
        f.unlink()
    for f in small.glob("*-rgb.png"):
        cv2.imwrite(str(f), cv2.resize(cv2.imread(str(f)), (160, 120), interpolation=cv2.INTER_AREA))
    for f in small.glob("*-depth.png"):
        depth = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(f), cv2.resize(depth, (160, 120), interpolation=cv2.INTER_NEAREST))
    K = read_intrinsics(small / "intrinsics.xml")
    K[:2] /= 2
    write_intrinsics(small / "intrinsics.xml", K)
    tracked = []
    monkeypatch.setattr(tracking, "track_sequence", lambda folder, *a, **k: tracked.append(folder))
    with pytest.raises(ValueError, match=r"roi: \(60, 50, 260, 190\) is not a box inside the 160 x 120 image .*sequence b"):
        write_tracking([first, small], tmp_path / "out", ("sift",), roi=(60, 50, 260, 190), progress=False)
    assert tracked == [] and not (tmp_path / "out").exists()


def test_a_descriptor_that_describes_too_few_template_keypoints_is_warned_of(tmp_path):
    """A ROI along the image border on the shipped Kinect frame: FREAK drops every keypoint there, so
    all its frames failed, even one identical to the template, and the tables said only "lost"."""
    import shutil

    from geofeat.io import demo_data_dir

    folder = tmp_path / "kinect"
    folder.mkdir()
    shutil.copy(demo_data_dir() / "intrinsics.xml", folder)
    for name in ("frame-000-master", "frame-001"):
        for suffix in ("rgb", "depth"):
            shutil.copy(demo_data_dir() / f"cloud_1-{suffix}.png", folder / f"{name}-{suffix}.png")
    with pytest.warns(UserWarning, match=r"sequence kinect: freak describes 0 of the \d+ template keypoints") as seen:
        results = track_sequence(folder, ("freak", "sift"), roi=(0, 20, 25, 460), refine="none", progress=False)
    assert not [w for w in seen if "sift describes" in str(w.message)]
    assert results["freak"].rows[0]["failed"] and not results["sift"].rows[0]["failed"]


def test_a_template_roi_without_depth_says_so(sequence, tmp_path):
    """The reference frame without depth in the ROI: the error said only that the ROI "holds 0
    keypoints", as if the template had no texture; keypoints are dropped where there is no depth."""
    import cv2

    folder = _public_copy(sequence, tmp_path / "public", "frame-001")
    path = folder / "frame-000-master-depth.png"
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    depth[60:180, 80:240] = 0
    cv2.imwrite(str(path), depth)
    with pytest.raises(ValueError, match=r"holds 0 keypoints .*0% of its pixels have depth"):
        track_sequence(folder, ("sift",), roi=(80, 60, 239, 179), refine="none", progress=False)


def test_too_few_keypoints_per_frame_are_named_not_the_roi(sequence, tmp_path):
    """`--keypoints 5`: the template could never hold the 10 keypoints it needs, whatever the ROI,
    but the error blamed the ROI ("roi: ... holds 5 keypoints")."""
    folder = _public_copy(sequence, tmp_path / "public", "frame-001")
    with pytest.raises(ValueError, match=r"^keypoints: 5 per frame, fewer than the 10"):
        track_sequence(folder, ("sift",), n_keypoints=5, refine="none", progress=False)


def test_a_failed_fit_counts_in_the_seconds_per_frame(sequence, tmp_path, monkeypatch):
    """A frame whose fit failed had seconds = NaN in track.csv, so tracking.md's "per frame, matching +
    RANSAC" time was the mean over the fitted frames only ("nan s" when every fit failed), although the
    failed frame had been matched and fitted too."""
    import re
    import types

    from geofeat.apps import tracking

    clock = _FakeClock()
    monkeypatch.setattr(tracking, "time", types.SimpleNamespace(perf_counter=clock.perf_counter))
    match_and_fit = tracking._match_and_fit

    def failing(template, target, name, *args):
        fit = match_and_fit(template, target, name, *args)
        clock.now += 0.1  # every fit takes 0.1 s
        if target.name == "frame-002":  # a slow fit that fails
            clock.now += 0.3
            fit = tracking._Fit(fit.i0, fit.i1, tracking.RansacResult(None, np.zeros(len(fit.i0), bool)))
        return fit

    monkeypatch.setattr(tracking, "_match_and_fit", failing)
    write_tracking([sequence], tmp_path, ("sift",), n_keypoints=300, refine="none", progress=False)
    rows = list(csv.DictReader(open(tmp_path / "track.csv")))
    assert [(r["frame"], r["failed"]) for r in rows] == [("frame-001", "False"), ("frame-002", "True")]
    seconds = [float(r["seconds"]) for r in rows]
    assert seconds == pytest.approx([0.1, 0.4])  # the failed frame's matching and RANSAC took time too
    shown = re.search(r"per frame, matching \+ RANSAC[^:]*: sift ([\d.]+) s", (tmp_path / "tracking.md").read_text())
    assert shown and float(shown.group(1)) == pytest.approx(np.mean(seconds), abs=1e-3)


def _real_sequence(folder, width=64, height=48):
    """Two frames of a textured plane at 1 m (colour, 16-bit depth and intrinsics only): a user's sequence."""
    from geofeat.io import write_frame, write_intrinsics

    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for name in ("view-ref", "view-2"):
        write_frame(folder, name, rng.integers(0, 256, (height, width, 3)).astype(np.uint8), np.ones((height, width)))
    write_intrinsics(folder / "intrinsics.xml", np.array([[60.0, 0, width / 2], [0, 60.0, height / 2], [0, 0, 1]]))
    return folder


def test_a_user_object_mask_of_16_bits_or_of_another_size_is_read_right_or_refused(tmp_path):
    """A 16-bit 0/1 (or 0/255) objmask was read as all zeros (IMREAD_GRAYSCALE), and one of another size
    put the default ROI in the wrong pixels, or failed with numpy's broadcasting message."""
    import cv2

    from geofeat.apps.objectmask import object_mask
    from geofeat.io import read_sequence

    seq = read_sequence(_real_sequence(tmp_path / "user"))
    tps = tmp_path / "tps" / "user"
    tps.mkdir(parents=True)
    box = np.zeros((48, 64), np.uint16)
    box[10:30, 20:50] = 1
    for values in (box, box * 255):
        cv2.imwrite(str(tps / "view-ref_objmask.png"), values)
        mask, source = object_mask(seq, "view-ref", tmp_path / "tps")
        assert source == "objmask" and mask.sum() == 600 and mask[10:30, 20:50].all()
        assert default_roi(mask) == (21, 11, 48, 28)
    cv2.imwrite(str(tps / "view-ref_objmask.png"), cv2.resize(box.astype(np.uint8) * 255, (32, 24)))
    with pytest.raises(ValueError, match="32x24.*64x48"):
        object_mask(seq, "view-ref", tmp_path / "tps")


def _photometric_cost(ref, tgt, mask, warp, config):
    """The refiner's photometric cost (1 - local NCC, object average, full resolution) of any warp."""
    import torch

    from geofeat.groundtruth import photometric as P

    ys, xs = np.nonzero(mask)
    s, (H, W) = float(config.spacing), ref.shape
    gx, gy = np.arange(xs.min() - s, xs.max() + 2 * s, s), np.arange(ys.min() - s, ys.max() + 2 * s, s)
    box = (max(int(xs.min() - s), 0), max(int(ys.min() - s), 0), min(int(xs.max() + s), W - 1), min(int(ys.max() + s), H - 1))
    level = P._Level(ref, tgt, mask, warp, box, gx, gy, 0, config.window, config.flat_tau)
    with torch.no_grad():
        warped, inside = P._warp(level, torch.zeros((2, len(gy), len(gx))))
        return float(P._ncc_cost(level, warped, inside, config.window, config.flat_tau))


def test_the_refined_warp_kept_is_the_map_whose_cost_the_refinement_measured():
    """refine_warp kept the refiner's node positions interpolated bilinearly, not its cubic B-spline
    field: a map the acceptance test never measured (on a simulated frame its cost was 0.415 where the
    refiner's was 0.395, its grid error 0.53 px instead of 0.48 px)."""
    import cv2

    from geofeat.apps.tracking import REFINE_ITERATIONS, refine_warp
    from geofeat.groundtruth import RefineConfig, refine

    rng = np.random.default_rng(1)
    H, W = 96, 128
    ref = cv2.GaussianBlur(rng.random((H, W)).astype(np.float32), (0, 0), 2.0)
    ref = (ref - ref.min()) / (ref.max() - ref.min())
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    dx, dy = 3 * np.sin(xx / 14) * np.cos(yy / 11), 3 * np.cos(xx / 9) * np.sin(yy / 13)
    tgt = cv2.remap(ref, xx - dx, yy - dy, cv2.INTER_LINEAR)  # about ref(p - d): the true map is near p + d
    src = np.stack(np.meshgrid(np.linspace(20, 107, 5), np.linspace(16, 79, 4)), -1).reshape(-1, 2)
    spline = fit_tps(src, src, 1e-3)  # the identity: the refinement has all of d to find
    mask = np.zeros((H, W), bool)
    mask[12:84, 16:112] = True
    config = RefineConfig(iterations=REFINE_ITERATIONS)
    warp, kept = refine_warp(ref, tgt, mask, spline, src, src, (16, 12, 111, 83), config)
    measured = refine(ref, tgt, mask, spline, src, src, config)
    assert kept and measured.cost < measured.init_cost
    assert abs(_photometric_cost(ref, tgt, mask, warp, config) - measured.cost) < 1e-4


def test_a_sequence_of_one_frame_is_refused_before_any_other_is_tracked(tmp_path, monkeypatch):
    """write_tracking tracked every sequence before it, then raised at the one-frame sequence and wrote
    nothing: all that work was lost."""
    import shutil

    from geofeat.apps import tracking

    two = _real_sequence(tmp_path / "data" / "a")
    one = tmp_path / "data" / "b"
    one.mkdir()
    for f in two.iterdir():
        if not f.name.startswith("view-2"):
            shutil.copy(f, one / f.name)
    def tracked(folder, *args, **kwargs):
        raise RuntimeError(f"{folder} tracked before the one-frame sequence was refused")

    monkeypatch.setattr(tracking, "track_sequence", tracked)
    with pytest.raises(ValueError, match="sequence b: needs a reference frame and at least one other"):
        write_tracking([tmp_path / "data"], tmp_path / "out", ("sift",), progress=False)
    assert not (tmp_path / "out").exists()


def test_every_track_csv_column_is_described_in_the_applications_page():
    """docs/applications.md described track.csv without precision, visible_grid, refined, n_template,
    n_frame or failed: columns a reader of the file found nowhere in the docs."""
    from pathlib import Path

    from geofeat.apps.tracking import TRACK_COLUMNS

    page = (Path(__file__).resolve().parents[1] / "docs" / "applications.md").read_text()
    described = page[page.index("Output: `track.csv`"):page.index("`<sequence>/<descriptor>/grid.npz`")]
    assert [c for c in TRACK_COLUMNS if f"`{c}`" not in described] == []


def _hide_landmarks(folder, frame: str, keep: int) -> None:
    """Mark all but the first `keep` landmarks of `frame`'s csv invisible (valid 0)."""
    path = folder / f"{frame}.csv"
    rows = list(csv.reader(open(path, newline="")))
    rows = rows[:1] + [r[:3] + ["1" if i < keep else "0"] for i, r in enumerate(rows[1:])]
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def test_a_frame_without_ground_truth_is_unscored_not_the_end_of_the_run(sequence, tmp_path, capsys):
    """A frame whose landmarks are mostly hidden (3 seen in both frames: no landmark spline), or that
    the TPS files of `geofeat groundtruth` leave out (it failed there), stopped the whole run with a
    message that did not name the frame; now it is tracked, its ground-truth figures NaN and said so."""
    from geofeat.groundtruth import GroundTruthConfig, generate_ground_truth

    folder = _public_copy(sequence, tmp_path / "public", "frame-001")
    _hide_landmarks(folder, "frame-002", 3)
    result = track_sequence(folder, ("sift",), n_keypoints=300, refine="none", progress=False)["sift"]
    rows = {r["frame"]: r for r in result.rows}
    assert rows["frame-001"]["grid_error_px"] == pytest.approx(0.0, abs=1e-6)
    assert not rows["frame-002"]["failed"] and np.isnan(rows["frame-002"]["grid_error_px"])
    assert np.isnan(rows["frame-002"]["precision"]) and np.isfinite(result.points[2]).all()
    assert "no ground truth for frame-002" in capsys.readouterr().out
    # the same frame left out of the TPS files that `geofeat groundtruth` writes (it fails there)
    tps = tmp_path / "tps"
    reports = generate_ground_truth(folder, tps / "public", GroundTruthConfig(refine=False), progress=False)
    assert [r.status for r in reports] == ["ok", "failed"]
    result = track_sequence(folder, ("sift",), n_keypoints=300, refine="none", progress=False, tps_dir=str(tps))["sift"]
    rows = {r["frame"]: r for r in result.rows}
    assert rows["frame-001"]["grid_error_px"] < 0.5 and np.isnan(rows["frame-002"]["grid_error_px"])
    assert "no ground truth for frame-002 (no frame-002_theta.npy in the TPS files)" in capsys.readouterr().out


def test_tps_files_asked_for_but_missing_for_a_sequence_are_refused_not_ignored(sequence, tmp_path):
    """--tps-dir without files for a sequence dropped its ground truth without a word (every grid
    error NaN, even those the simulator's truth measures); now it is refused before any work."""
    other = tmp_path / "tps" / "another-sequence"
    other.mkdir(parents=True)
    cv2 = pytest.importorskip("cv2")
    cv2.imwrite(str(other / "frame-000-master_objmask.png"), np.full((240, 320), 255, np.uint8))
    with pytest.raises(ValueError, match="tps-dir: no TPS files .* sequence cloth"):
        track_sequence(sequence, ("sift",), n_keypoints=300, refine="none", progress=False, tps_dir=str(tmp_path / "tps"))
    with pytest.raises(ValueError, match="tps-dir: no TPS files .* sequence cloth"):
        write_tracking([sequence], tmp_path / "out", ("sift",), n_keypoints=300, refine="none", progress=False,
                       tps_dir=str(tmp_path / "tps"))
    assert not (tmp_path / "out").exists()


def test_grid_points_thrown_off_the_cloth_count_as_lost_not_as_left_out(sequence):
    """A tracked grid point that the ground truth maps nowhere was left out of grid_error_px: a warp
    that threw 60 % of the visible grid onto the background scored 0 px, better than one that
    tracked those points 8 px off on the cloth. Where the simulator sees the grid point in the frame,
    its true position maps back onto it, so such a point is misplaced: it counts as lost."""
    from geofeat.apps.objectmask import object_mask
    from geofeat.apps.tracking import _grid_error
    from geofeat.groundtruth.sources import GroundTruth
    from geofeat.io import read_sequence

    seq = read_sequence(sequence)
    truth = GroundTruth(seq, None)
    target = seq.targets[0]
    grid = roi_grid(default_roi(object_mask(seq, seq.reference)[0]))
    xy, seen = truth.project(target, grid)
    use = seen & truth.reference_keep(grid)
    assert use.sum() >= 20
    grid, xy = grid[use], xy[use]
    projected = truth.project(target, grid)
    assert _grid_error(truth, target, xy, grid, projected) == pytest.approx(0.0, abs=1e-6)  # a perfect track
    lost = np.arange(len(grid)) < int(0.6 * len(grid))
    off, near = xy.copy(), xy.copy()
    off[lost] = [0.0, 0.0]  # onto the background (the image corner)
    near[lost] += [8.0, 0.0]
    assert not truth.map(target, off[:1])[1].any()
    near_error = _grid_error(truth, target, near, grid, projected)
    assert 4.0 < near_error < 12.0
    assert _grid_error(truth, target, off, grid, projected) == np.inf  # more than half of the grid lost
    # without the simulator's forward truth (TPS files, landmarks) such a point cannot be judged: left out
    assert _grid_error(truth, target, off, grid) == pytest.approx(0.0, abs=1e-6)


def test_a_users_file_at_a_result_path_is_refused_before_any_tracking(sequence, tmp_path, monkeypatch):
    """A file geofeat did not write at OUT/<sequence>/<descriptor>/grid.npz was refused only when the
    results were moved into place, after all the tracking; a rerun over geofeat's own results still
    replaces them."""
    from geofeat.apps import tracking

    write_tracking([sequence], tmp_path / "out", ("sift",), n_keypoints=300, refine="none", progress=False)
    write_tracking([sequence], tmp_path / "out", ("sift",), n_keypoints=300, refine="none", progress=False,
                   overwrite=True)  # geofeat's own files: replaced
    mine = tmp_path / "mine" / sequence.name / "orb"
    mine.mkdir(parents=True)
    (mine / "grid.npz").write_bytes(b"my own grid")
    monkeypatch.setattr(tracking, "track_sequence", lambda *a, **k: pytest.fail("tracked before the refusal"))
    with pytest.raises(ValueError, match="which geofeat did not write"):
        write_tracking([sequence], tmp_path / "mine", ("orb",), n_keypoints=300, refine="none", progress=False,
                       overwrite=True)
    assert (mine / "grid.npz").read_bytes() == b"my own grid"


def _failing_fits(monkeypatch, frames):
    """Make the fit of the target frames named in `frames` fail (`_match_and_fit` keeps no warp)."""
    from geofeat.apps import tracking

    match_and_fit = tracking._match_and_fit

    def failing(template, target, name, *args):
        fit = match_and_fit(template, target, name, *args)
        if target.name in frames:
            fit = tracking._Fit(fit.i0, fit.i1, tracking.RansacResult(None, np.zeros(len(fit.i0), bool)))
        return fit

    monkeypatch.setattr(tracking, "_match_and_fit", failing)


def test_track_command_that_tracked_no_frame_fails(sequence, tmp_path, capsys, monkeypatch):
    """`geofeat track` exited 0 when the fit failed in every target frame: a run that tracked nothing
    read as a success. It now exits 1 and says that no frame was tracked."""
    from geofeat.cli import main

    _failing_fits(monkeypatch, ("frame-001", "frame-002"))
    args = ["track", str(sequence), "--descriptors", "sift", "--keypoints", "300", "--refine", "none"]
    assert main([*args, "--out", str(tmp_path / "none")]) == 1
    assert "no frame was tracked" in capsys.readouterr().err
    rows = list(csv.DictReader(open(tmp_path / "none" / "track.csv")))
    assert [r["failed"] for r in rows] == ["True", "True"]  # the failed rows are still written


def test_track_command_that_tracked_some_frames_succeeds_and_counts_the_failures(sequence, tmp_path, capsys,
                                                                                 monkeypatch):
    from geofeat.cli import main

    _failing_fits(monkeypatch, ("frame-002",))
    args = ["track", str(sequence), "--descriptors", "sift", "--keypoints", "300", "--refine", "none"]
    assert main([*args, "--out", str(tmp_path / "some")]) == 0
    captured = capsys.readouterr()
    assert "no frame was tracked" not in captured.err
    assert "| 1/2 |" in captured.out  # the table's failed frames
