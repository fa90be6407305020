"""Matching-score protocol: hand counts, random descriptors, TPS ground truth."""

import numpy as np
import pytest

from geofeat.groundtruth.landmarks import inside_hull, landmark_spline
from geofeat.tps import ThinPlateSpline
from geofeat.scoring import ground_truth_pairs, score_detect, score_landmarks
from geofeat.features import Features
from geofeat.matching import match


def test_hand_counted_pair():
    ref = np.array([[10, 10], [50, 50], [90, 90], [130, 130.0]])
    # target keypoints mapped into the reference: t0 -> r1 (1 px), t1 -> r0 (2.9 px), t2 -> r1 again
    # (dropped: r1 already taken by t0), t3 -> nothing (5 px from r3), t4 -> r2 (0 px)
    tgt_in_ref = np.array([[51, 50], [10, 12.9], [50, 50], [135, 130], [90, 90.0]])
    pairs = ground_truth_pairs(ref, tgt_in_ref)
    np.testing.assert_array_equal(pairs, [[1, 0], [0, 1], [2, 4]])
    matches0 = np.array([1, 2, 4, 3])  # r0 -> t1 hit, r1 -> t2 miss (gt is t0), r2 -> t4 hit
    s = score_detect(matches0, pairs, n_ref=4, n_tgt=5)
    assert (s.hits, s.n_gt) == (2, 3)
    assert s.ms == pytest.approx(2 / 4) and s.mma == pytest.approx(2 / 3)


def test_threshold_is_strict_and_nan_is_skipped():
    ref = np.array([[0, 0.0]])
    assert len(ground_truth_pairs(ref, np.array([[3.0, 0.0]]))) == 0
    assert len(ground_truth_pairs(ref, np.array([[2.99, 0.0]]))) == 1
    assert len(ground_truth_pairs(ref, np.array([[np.nan, np.nan]]))) == 0
    assert ground_truth_pairs(np.zeros((0, 2)), np.zeros((3, 2))).shape == (0, 2)


def test_random_descriptors_score_about_one_over_n_and_identical_score_one():
    rng = np.random.default_rng(0)
    n = 200
    xy = rng.uniform(0, 640, (n, 2))
    pairs = ground_truth_pairs(xy, xy)
    assert len(pairs) == n
    ms_random = []
    for seed in range(10):
        r = np.random.default_rng(seed)
        m = match(Features(xy, r.random((n, 32)).astype(np.float32), None), Features(xy, r.random((n, 32)).astype(np.float32), None))
        ms_random.append(score_detect(m.matches0, pairs, n, n).ms)
    assert np.mean(ms_random) < 5 / n
    d = rng.random((n, 32)).astype(np.float32)
    m = match(Features(xy, d, None), Features(xy, d, None))
    assert score_detect(m.matches0, pairs, n, n).ms == 1.0


def test_landmarks_protocol():
    ref_ids = np.array([0, 1, 2, 3])
    tgt_ids = np.array([1, 2, 3, 7])  # landmark 0 invisible in the target
    matches0 = np.array([0, 0, 2, 1])  # 0 -> id1 (not a query), 1 -> id1 hit, 2 -> id3 miss, 3 -> id2 miss
    s = score_landmarks(matches0, ref_ids, tgt_ids)
    assert (s.hits, s.n_gt) == (1, 3) and s.ms == pytest.approx(1 / 3)


def test_landmark_tps_reproduces_a_smooth_warp():
    rng = np.random.default_rng(1)
    tgt = rng.uniform(50, 590, (60, 2))

    def warp(p):
        return np.stack([p[:, 0] + 10 * np.sin(p[:, 1] / 100), p[:, 1] + 0.05 * p[:, 0]], axis=1)

    tps = landmark_spline(tgt, warp(tgt))
    q = rng.uniform(150, 450, (100, 2))
    err = np.linalg.norm(tps(q) - warp(q), axis=1)
    assert np.median(err) < 0.5
    assert inside_hull(tgt, q).all() and not inside_hull(tgt, np.array([[0.0, 0.0]]))[0]
    with pytest.raises(ValueError, match="landmarks"):
        landmark_spline(tgt[:3], tgt[:3])


def test_authors_tps_identity_and_affine():
    ctrl = np.random.default_rng(2).random((10, 2))
    theta = np.zeros((1, 13, 2))
    xy = np.array([[100.0, 200.0], [320, 240]])
    np.testing.assert_allclose(ThinPlateSpline.from_authors_arrays(theta, ctrl, (640, 480))(xy), xy)
    theta[0, 10] = [0.1, -0.05]  # constant offset in normalised coordinates
    np.testing.assert_allclose(ThinPlateSpline.from_authors_arrays(theta, ctrl, (640, 480))(xy), xy + [64, -24])
