"""GeoKey, the learned deformation-aware detector: repeatable on an isometrically bent sheet (better
than the same network with random weights), deterministic, clear errors, and the bench with both
detectors on a tiny simulated sequence."""

import hashlib
import json
import warnings

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

import geofeat
from geofeat.bench.report import read_results
from geofeat.bench.runner import BenchConfig, run_benchmark
from geofeat.detectors.geokey import (SHIPPED_WEIGHTS, GeoKeyModel, candidates, detect_geokey, load_geokey,
                                      local_cornerness, noise_corner_share, suppress)
from geofeat.sim import simulate_sequence
from geofeat.train.detector import (SIFT_KEY, admissible_threshold, choose_model, fit, mean_ms, sequence_samples,
                                    with_level_bias)

from sheets import K_SHEET, make_texture, project_bent, project_flat, render_bent, render_flat

Z0, BEND = 0.6, 0.12


def _bent_repeatability(detector, n: int = 400) -> float:
    """Share of the flat sheet's keypoints (inside the part of the sheet the bent view sees) that
    have a keypoint of the bent view within 3 px of their exact position there."""
    tex = make_texture(3)
    flat, bent = render_flat(tex, Z0), render_bent(tex, Z0, BEND)
    k_flat, k_bent = detector(flat, n), detector(bent, n)
    # flat pixel -> material (u, v) -> bent pixel
    uv = np.stack([(k_flat.xy[:, 0] - K_SHEET[0, 2]) * Z0 / K_SHEET[0, 0],
                   (k_flat.xy[:, 1] - K_SHEET[1, 2]) * Z0 / K_SHEET[1, 1]], axis=1)
    seen = np.abs(uv[:, 0]) < 0.6 * BEND * np.pi / 2  # well inside the bent view's silhouette
    mapped = project_bent(uv[seen], Z0, BEND)
    inside = (mapped[:, 0] > 8) & (mapped[:, 0] < 632) & (mapped[:, 1] > 8) & (mapped[:, 1] < 472)
    dist, _ = cKDTree(k_bent.xy).query(mapped[inside])
    return float(np.mean(dist < 3.0))


def _random_model(seed: int = 0) -> GeoKeyModel:
    shipped = load_geokey()
    rng = np.random.default_rng(seed)
    weights = tuple(rng.normal(size=w.shape).astype(np.float32) for w in shipped.weights)
    linear = rng.normal(size=shipped.linear.shape).astype(np.float32)
    return GeoKeyModel(shipped.mean, shipped.std, linear, weights, shipped.biases, shipped.nms_radius)


def test_geokey_is_repeatable_on_a_bent_sheet_and_beats_random_weights():
    trained = _bent_repeatability(lambda f, n: geofeat.detect(f, n, detector="geokey"))
    random = np.mean([_bent_repeatability(lambda f, n, s=s: detect_geokey(f, n, _random_model(s))) for s in range(3)])
    assert trained > 0.6, trained
    assert trained > random + 0.05, (trained, random)


def test_projections_of_the_test_sheet_agree():
    """The check above relies on flat pixel -> material -> bent pixel; the flat round trip is exact."""
    uv = np.array([[0.01, -0.02], [0.0, 0.05]])
    xy = project_flat(uv, Z0)
    back = np.stack([(xy[:, 0] - K_SHEET[0, 2]) * Z0 / K_SHEET[0, 0], (xy[:, 1] - K_SHEET[1, 2]) * Z0 / K_SHEET[1, 1]], 1)
    np.testing.assert_allclose(back, uv, atol=1e-12)


def test_detect_geokey_returns_sorted_unique_keypoints_on_depth():
    frame = geofeat.read_demo_frame()
    kps = geofeat.detect(frame, 500, detector="geokey")
    assert 0 < len(kps) <= 500
    assert np.all(np.diff(kps.responses) <= 0)
    xi, yi = np.rint(kps.xy).astype(int).T
    assert np.all(frame.depth[yi, xi] > 0)
    d, _ = cKDTree(kps.xy).query(kps.xy, k=2)
    assert d[:, 1].min() >= load_geokey().nms_radius - 1.0  # suppression keeps keypoints apart
    again = geofeat.detect(frame, 500, detector="geokey")
    np.testing.assert_array_equal(kps.xy, again.xy)


def test_mask_restricts_geokey():
    frame = geofeat.read_demo_frame()
    mask = np.zeros(frame.shape, np.uint8)
    mask[:, : frame.shape[1] // 2] = 1
    kps = geofeat.detect(frame, 300, detector="geokey", mask=mask)
    assert len(kps) and np.all(kps.xy[:, 0] < frame.shape[1] // 2 + 0.5)


def test_suppression_keeps_the_local_maximum_only():
    xy = np.array([[10.0, 10.0], [11.0, 10.0], [30.0, 30.0]])
    keep = suppress(xy, np.array([1.0, 2.0, 0.5]), 3, (50, 50))
    assert keep.tolist() == [False, True, True]


def test_no_candidate_on_an_occlusion_contour_but_on_a_steep_slope():
    """A textured scene whose right part stands 30 cm behind (an occlusion contour at column 80) and
    whose bottom rows slope at 80 degrees: candidates stay DEPTH_EDGE_MARGIN_PX off the contour and
    off the holes, and are still found on the slope and elsewhere."""
    from geofeat.detectors.cues import depth_edge_distance
    from geofeat.detectors.geokey import DEPTH_EDGE_MARGIN_PX

    tex = make_texture(3, 256)[:120, :160].astype(np.float32)
    depth = np.full((120, 160), 1.0, np.float32)
    depth[:, 80:] = 1.3
    fx = float(K_SHEET[0, 0])
    rows = np.arange(80, 120)
    depth[80:, :80] = (1.0 + np.tan(np.radians(80)) * (rows - 79) / fx)[:, None]  # 80-degree slope
    depth[10:20, 10:20] = 0.0  # a hole
    frame = geofeat.RGBDFrame(tex, depth, K_SHEET)
    xy = candidates(frame).xy
    dist = depth_edge_distance(depth, fx, 10.0)
    assert len(xy) > 50
    assert (dist[np.rint(xy[:, 1]).astype(int), np.rint(xy[:, 0]).astype(int)] >= DEPTH_EDGE_MARGIN_PX).all()
    assert not (np.abs(xy[:, 0] - 79.5) < 2.5).any()  # the contour between columns 79 and 80
    assert not ((xy[:, 0] > 7) & (xy[:, 0] < 22) & (xy[:, 1] > 7) & (xy[:, 1] < 22)).any()  # around the hole
    assert ((xy[:, 1] > 83) & (xy[:, 1] < 115) & (xy[:, 0] < 75)).sum() > 5  # the steep slope keeps its corners


def test_depth_edge_distance_matches_its_definition():
    """Distance to the nearest pixel whose depth steps by more than k footprints to its right or lower
    neighbour, or that has no depth: against a direct computation (brute-force Euclidean distance;
    OpenCV's 3x3 mask approximates it within 5 %)."""
    from geofeat.detectors.cues import depth_edge_distance

    rng = np.random.default_rng(1)
    depth = (1.0 + 0.002 * rng.standard_normal((40, 50))).astype(np.float32)
    depth[:, 30:] += 0.2  # a contour
    depth[5:8, 5:9] = 0.0  # a hole
    fx = 500.0
    fp = np.where(depth > 0, depth / fx, 1.0)
    right = np.zeros(depth.shape, bool)
    below = np.zeros(depth.shape, bool)
    right[:, :-1] = np.abs(depth[:, 1:] - depth[:, :-1]) / fp[:, :-1] > 10.0
    below[:-1] = np.abs(depth[1:] - depth[:-1]) / fp[:-1] > 10.0
    edge = (depth <= 0) | right | below
    ey, ex = np.nonzero(edge)
    yy, xx = np.mgrid[:40, :50]
    truth = np.sqrt((yy[..., None] - ey) ** 2 + (xx[..., None] - ex) ** 2).min(axis=-1)
    got = depth_edge_distance(depth, fx, 10.0)
    assert (got[edge] == 0).all() and (got[~edge] > 0).all()
    np.testing.assert_allclose(got, truth, rtol=0.05, atol=1e-6)
    assert not edge[:, 31:].any() and edge[:, 29].all()  # the 2 mm noise is no edge; the 20 cm step is


def test_frame_without_texture_or_depth_gives_no_keypoints_and_a_warning():
    K = K_SHEET
    blank = geofeat.RGBDFrame(np.full((120, 160), 0.5, np.float32), np.full((120, 160), 1.0, np.float32), K)
    with pytest.warns(UserWarning, match="geokey"):
        assert len(geofeat.detect(blank, 100, detector="geokey")) == 0
    tex = (make_texture(1, 256)[:120, :160]).astype(np.float32)
    depth = np.zeros((120, 160), np.float32)
    depth[0, 0] = 1.0  # RGBDFrame refuses an all-zero depth map
    no_depth = geofeat.RGBDFrame(tex, depth, K)
    with pytest.warns(UserWarning, match="geokey"):
        assert len(geofeat.detect(no_depth, 100, detector="geokey")) == 0


def test_a_blank_frame_with_faint_noise_warns_that_no_candidate_reaches_the_threshold():
    """Uniform grey with noise of a tenth of an 8-bit grey level: no candidate reaches the shipped
    threshold, yet the min_fraction floor kept its best 35 % (about 1900 keypoints, more than the
    Kinect frame gives) without a word. The keypoints are kept (the floor's documented rule); a warning
    says they come from the floor alone. The Kinect frame, where hundreds reach it, does not warn."""
    frame = geofeat.read_demo_frame()
    noise = np.random.default_rng(0).normal(0.5, 4e-4, frame.shape).astype(np.float32)
    blank = geofeat.RGBDFrame(noise, frame.depth, frame.K)
    with pytest.warns(UserWarning, match=r"geokey: no candidate reaches the score threshold .*\(min_fraction\)"):
        assert len(geofeat.detect(blank, 100, detector="geokey")) == 100
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(geofeat.detect(frame, 100, detector="geokey")) == 100
        detect_geokey(blank, 100, threshold=np.inf, min_fraction=1.0)  # the floor alone, asked for: no warning


def test_local_cornerness_is_opencvs_smaller_eigenvalue_at_the_strongest_of_nine_pixels():
    """The noise check's corner strength is the structure tensor's smaller eigenvalue (Shi-Tomasi,
    what GeoKey's candidates maximise), up to OpenCV's constant scale, taken at the strongest of the
    3 x 3 pixels around each position."""
    frame = geofeat.read_demo_frame()
    image = frame.image.astype(np.float32)
    rng = np.random.default_rng(0)
    xy = np.stack([rng.uniform(10, 629, 400), rng.uniform(10, 469, 400)], 1)
    ours = local_cornerness(image, xy)
    opencv = cv2.dilate(cv2.cornerMinEigenVal(image, 3, 3), np.ones((3, 3), np.uint8))
    theirs = opencv[np.rint(xy[:, 1]).astype(int), np.rint(xy[:, 0]).astype(int)]
    strong = theirs > 1e-7
    assert strong.mean() > 0.9
    ratio = ours[strong] / theirs[strong]
    assert ratio.std() < 1e-4 * ratio.mean()
    np.testing.assert_array_equal(ours[~strong] < 1e-6, True)


@pytest.mark.parametrize("grey_levels", [2.5, 5.0, 10.0])
def test_a_textureless_noisy_frame_warns_that_its_keypoints_are_noise(grey_levels):
    """A uniform surface with sensor noise of a few grey levels: candidates reach GeoKey's threshold
    (at 5 and 10 levels), so the floor's warning is silent, and it returned about 1900 keypoints on pure
    noise without a word. A warning now says that few of them are stronger corners than the noise.
    The Kinect frame, as it is and with 5 grey levels of noise added, does not warn."""
    frame = geofeat.read_demo_frame()
    noise = np.random.default_rng(1).normal(0.5, grey_levels / 255, frame.shape).clip(0, 1).astype(np.float32)
    blank = geofeat.RGBDFrame(noise, frame.depth, frame.K)
    said = "stronger corners than its image noise" if grey_levels >= 5 else r"only the floor"  # none reaches it at 2.5
    with pytest.warns(UserWarning, match=f"geokey: .*{said}"):
        assert len(geofeat.detect(blank, 2048, detector="geokey")) > 1000
    assert noise_corner_share(blank.image, geofeat.detect(blank, 2048, detector="geokey").xy) < 0.15
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kps = geofeat.detect(frame, 2048, detector="geokey")
        assert noise_corner_share(frame.image, kps.xy) > 0.9
        noisy = np.clip(frame.image + np.random.default_rng(2).normal(0, 5 / 255, frame.shape), 0, 1)
        geofeat.detect(geofeat.RGBDFrame(noisy.astype(np.float32), frame.depth, frame.K), 2048, detector="geokey")


@pytest.mark.parametrize("n", [0, -5, 2.5])
def test_bad_n_is_an_error(n):
    frame = geofeat.read_demo_frame()
    with pytest.raises(ValueError, match="n:"):
        geofeat.detect(frame, n, detector="geokey")


@pytest.mark.parametrize("detector", ["geokey", "sift"])
def test_a_float_n_is_refused_as_not_whole(detector):
    """n=2048.0 was refused with 'expected a positive number of keypoints, got 2048.0': a positive
    number, so the message did not say what was wrong (an int is expected)."""
    with pytest.raises(ValueError, match="n: expected a positive whole number of keypoints, an int"):
        geofeat.detect(geofeat.read_demo_frame(), 2048.0, detector=detector)


@pytest.mark.parametrize("option", ["threshold", "min_fraction", "denoise"])
def test_a_geokey_option_with_sift_says_it_is_geokeys(option):
    """detect(frame, detector="sift", threshold=...) failed with "detect_sift() got an unexpected keyword
    argument 'threshold'", naming a function the user did not call and not SIFT's own threshold; now
    it says the option is GeoKey's, as GeoKey names SIFT's options."""
    with pytest.raises(TypeError, match=f"{option}.*apply to 'geokey' only.*contrast_threshold"):
        geofeat.detect(geofeat.read_demo_frame(), 10, detector="sift", **{option: 0.5})


def test_a_sift_keypoint_set_with_geokey_is_an_error():
    """'protocol' picks among SIFT's duplicate keypoints; GeoKey's are unique, so only 'unique' is accepted."""
    frame = geofeat.read_demo_frame()
    with pytest.raises(ValueError, match="keypoint_set"):
        geofeat.detect(frame, 50, detector="geokey", keypoint_set="protocol")
    with pytest.raises(ValueError, match="keypoint_set"):
        BenchConfig(descriptors=("geobit",), detector="geokey", keypoint_set="protocol")
    unique = geofeat.detect(frame, 50, detector="geokey", keypoint_set="unique")
    np.testing.assert_array_equal(unique.xy, geofeat.detect(frame, 50, detector="geokey").xy)
    assert BenchConfig(descriptors=("geobit",), detector="geokey").keypoint_set == "unique"
    assert BenchConfig(descriptors=("geobit",)).keypoint_set == "protocol"


def test_bad_detector_names_and_weights_files(tmp_path):
    frame = geofeat.read_demo_frame()
    with pytest.raises(ValueError, match="detector"):
        geofeat.detect(frame, 10, detector="surf")
    with pytest.raises(ValueError, match="does not exist"):
        geofeat.detect(frame, 10, detector=f"geokey={tmp_path / 'missing.pt'}")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not weights")
    with pytest.raises(ValueError, match="corrupt.pt"):
        geofeat.detect(frame, 10, detector=f"geokey={corrupt}")
    other = tmp_path / "other.pt"
    np.savez(open(other, "wb"), w0=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="other.pt"):
        geofeat.detect(frame, 10, detector=f"geokey={other}")
    with pytest.raises(ValueError, match="detector"):
        BenchConfig(descriptors=("geobit",), detector="geokey=")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("geokey")
    simulate_sequence(root / "seqs" / "a-deform", scenario="deform", n_frames=3, seed=21,
                      width=320, height=240, progress=False)
    return root / "seqs"


def test_training_labels_and_same_seed_same_weights(tiny, tmp_path):
    seq = geofeat.read_sequence(tiny / "a-deform")
    x, y = sequence_samples(seq)
    assert x.shape[0] == y.shape[0] > 100 and 0 < y.mean() < 1
    x_filtered, _ = sequence_samples(seq, denoise=4.0, max_targets=1)  # candidates and cues of the filtered image
    x_one, _ = sequence_samples(seq, max_targets=1)
    assert x_filtered.shape != x_one.shape or not np.array_equal(x_filtered, x_one)
    a = fit(x, y, hidden=(8,), steps=30, batch=256, seed=3, device="cpu", progress=False)
    b = fit(x, y, hidden=(8,), steps=30, batch=256, seed=3, device="cpu", progress=False)
    for wa, wb in zip(a.weights, b.weights):
        np.testing.assert_array_equal(wa, wb)
    a.save(tmp_path / "a.pt")
    frame = seq.frame(seq.reference)
    k1 = geofeat.detect(frame, 200, detector=f"geokey={tmp_path / 'a.pt'}")
    k2 = detect_geokey(frame, 200, a)
    np.testing.assert_array_equal(k1.xy, k2.xy)
    # "matchable" labels are a subset of "repeatable" ones
    x_m, y_m = sequence_samples(seq, labels="matchable", max_targets=1)
    x_r, y_r = sequence_samples(seq, labels="repeatable", max_targets=1)
    np.testing.assert_array_equal(x_m, x_r)
    assert np.all(y_m <= y_r) and y_m.sum() > 0


def test_the_suppression_radius_and_level_bias_are_chosen_by_the_mean_score_over_keypoint_counts(tiny):
    shipped = load_geokey()
    model, results, chosen = choose_model({"shipped": shipped}, [tiny / "a-deform"], counts=(100, 300),
                                          radii=(2.0, 5.0), level_biases=(0.0, -3.0), thresholds=(), progress=False)
    stage1 = max([("shipped", 2.0), ("shipped", 5.0)], key=lambda key: mean_ms(results[key]))
    assert set(results) == {("shipped", 2.0), ("shipped", 5.0), ("shipped, level 1 -3", stage1[1])}
    for per_count in results.values():
        assert set(per_count) == {100, 300}
        for r in per_count.values():
            assert 0 <= r["ms"] <= r["repeatability"] <= 1
    best = max(results, key=lambda key: mean_ms(results[key]))
    assert chosen == best and model.nms_radius == best[1]
    expected = with_level_bias(shipped, -3.0) if best[0].endswith("-3") else shipped
    np.testing.assert_array_equal(model.linear, expected.linear)
    with pytest.raises(ValueError, match="keypoints"):
        choose_model({"shipped": shipped}, [tiny / "a-deform"], counts=(0,), progress=False)


def test_a_score_threshold_is_kept_only_when_it_leaves_sifts_keypoints_and_correct_matches(tiny):
    sift = {100: {"n_ref": 90.0, "hits": 30.0}, 300: {"n_ref": 200.0, "hits": 50.0}}
    ok = {100: {"n_ref": 95.0, "hits": 40.0}, 300: {"n_ref": 210.0, "hits": 60.0}}
    assert admissible_threshold(ok, sift, min_keypoints=150)
    assert not admissible_threshold(ok, sift, min_keypoints=250)  # too few at the largest count
    assert not admissible_threshold({**ok, 100: {"n_ref": 80.0, "hits": 40.0}}, sift, 150)  # fewer keypoints than SIFT
    assert not admissible_threshold({**ok, 300: {"n_ref": 210.0, "hits": 45.0}}, sift, 150)  # fewer correct matches
    shipped = load_geokey()
    model, results, chosen = choose_model({"shipped": shipped}, [tiny / "a-deform"], counts=(150,), radii=(3.0,),
                                          level_biases=(0.0,), thresholds=(-np.inf, 0.5, 99.0), keep_fraction=0.2,
                                          progress=False)
    assert SIFT_KEY in results and ("shipped, threshold 99", 3.0) in results
    assert results[("shipped, threshold 99", 3.0)][150]["n_ref"] == 0  # evaluated without the floor
    assert chosen != ("shipped, threshold 99", 3.0)  # keeps no keypoint: never admissible
    admissible = [key for key in results if key != SIFT_KEY
                  and (key == ("shipped", 3.0) or admissible_threshold(results[key], results[SIFT_KEY]))]
    assert chosen == max(admissible, key=lambda key: mean_ms(results[key]))
    if chosen == ("shipped, threshold 0.5", 3.0):  # a chosen threshold comes with the floor
        assert (model.threshold, model.min_fraction) == pytest.approx((0.5, 0.2))
    else:
        assert (model.threshold, model.min_fraction) == (-np.inf, 0.0)


def test_the_score_threshold_drops_low_scores_and_travels_with_the_weights(tmp_path):
    frame = geofeat.read_demo_frame()
    shipped = load_geokey()
    everything = detect_geokey(frame, 0, shipped, threshold=-np.inf)
    t = float(np.median(everything.responses))
    kept = detect_geokey(frame, 0, shipped, threshold=t, min_fraction=0.0)
    assert len(kept) == int(np.sum(everything.responses >= t)) and kept.responses.min() >= t
    np.testing.assert_array_equal(kept.xy, everything.xy[: len(kept)])  # the same ranking, cut at t
    assert len(detect_geokey(frame, 50, shipped, threshold=-np.inf)) == 50
    model = GeoKeyModel(shipped.mean, shipped.std, shipped.linear, shipped.weights, shipped.biases,
                        shipped.nms_radius, t, 0.1)
    model.save(tmp_path / "t.npz")
    assert load_geokey(tmp_path / "t.npz").threshold == pytest.approx(t)
    assert load_geokey(tmp_path / "t.npz").min_fraction == pytest.approx(0.1)
    np.testing.assert_array_equal(geofeat.detect(frame, None, detector=f"geokey={tmp_path / 't.npz'}").xy, kept.xy)
    np.testing.assert_array_equal(geofeat.detect(frame, None, detector="geokey", threshold=t, min_fraction=0).xy, kept.xy)
    with pytest.warns(UserWarning, match="threshold"):
        assert len(detect_geokey(frame, 10, shipped, threshold=1e6, min_fraction=0.0)) == 0
    with pytest.raises(ValueError, match="threshold"):
        detect_geokey(frame, 10, shipped, threshold=float("nan"))
    old = dict(np.load(tmp_path / "t.npz"))
    del old["threshold"], old["min_fraction"]  # weights written before the selection rule existed
    np.savez(open(tmp_path / "old.npz", "wb"), **old)
    assert (load_geokey(tmp_path / "old.npz").threshold, load_geokey(tmp_path / "old.npz").min_fraction) == (-np.inf, 0.0)


def test_a_fraction_of_the_candidates_is_kept_whatever_the_threshold():
    frame = geofeat.read_demo_frame()
    shipped = load_geokey()
    everything = detect_geokey(frame, 0, shipped, threshold=-np.inf)
    quarter = detect_geokey(frame, 0, shipped, threshold=np.inf, min_fraction=0.25)
    assert len(quarter) == int(0.25 * len(everything))
    np.testing.assert_array_equal(quarter.xy, everything.xy[: len(quarter)])
    t = float(everything.responses[len(everything) // 2])  # half of them reach t
    either = detect_geokey(frame, 0, shipped, threshold=t, min_fraction=0.25)
    assert len(either) == int(np.sum(everything.responses >= t))  # the larger of the two
    assert len(detect_geokey(frame, 100, shipped, threshold=np.inf, min_fraction=0.25)) == 100  # at most n
    with pytest.raises(ValueError, match="min_fraction"):
        detect_geokey(frame, 10, shipped, min_fraction=1.5)


def test_a_level_bias_moves_half_resolution_candidates_only(tiny):
    frame = geofeat.read_sequence(tiny / "a-deform").frame(0)
    shipped = load_geokey()
    cands = candidates(frame)
    from geofeat.detectors.geokey import candidate_features

    x = candidate_features(frame, cands, depth_cues=shipped.uses_depth_cues)
    delta = with_level_bias(shipped, -1.0).score(x) - shipped.score(x)
    d0, d1 = delta[cands.level == 0], delta[cands.level == 1]
    assert len(d0) and len(d1)
    np.testing.assert_allclose(d0, d0[0], atol=1e-4)  # one shift per level: the ranking within a level stays
    np.testing.assert_allclose(d1 - d0[0], -1.0, atol=1e-4)


def test_bench_runs_with_both_detectors(tiny, tmp_path):
    for detector in ("sift", "geokey"):
        config = BenchConfig(descriptors=("geobit",), n_keypoints=300, detector=detector)
        csv_path, failed = run_benchmark(tiny, tmp_path / detector, config, progress=False)
        rows = read_results(csv_path)
        assert not failed and len(rows) == 2
        for r in rows:
            assert r["detector"] == detector
            assert 0 <= r["ms"] <= r["repeatability"] <= 1
            assert r["hits"] <= r["n_gt"] <= min(r["n_ref"], r["n_tgt"])
        # config.json says what made the numbers: the version and, for GeoKey, which weights
        made = json.loads((tmp_path / detector / "config.json").read_text())["provenance"]
        assert made["geofeat"] == geofeat.__version__ and "geopatch_backend" not in made
        if detector == "geokey":
            assert made["detector_weights_sha256"] == hashlib.sha256(SHIPPED_WEIGHTS.read_bytes()).hexdigest()
        else:
            assert "detector_weights_sha256" not in made


def test_candidates_lie_on_depth_inside_the_image():
    frame = geofeat.read_demo_frame()
    cands = candidates(frame)
    xy = cands.xy
    assert len(xy) > 1000 and set(np.unique(cands.level)) == {0, 1}
    xi, yi = np.rint(xy).astype(int).T
    assert np.all(frame.depth[yi, xi] > 0)
    H, W = frame.shape
    assert xy[:, 0].min() >= 0 and xy[:, 0].max() <= W - 1 and xy[:, 1].min() >= 0 and xy[:, 1].max() <= H - 1


def test_extract_is_detect_then_describe():
    frame = geofeat.read_demo_frame()
    f = geofeat.extract(frame, n=300, detector="geokey", descriptor="geobit")
    kps = geofeat.detect(frame, 300, detector="geokey")
    np.testing.assert_array_equal(f.keypoints, kps.xy)
    assert f.descriptors.shape == (len(kps), 16, 64) and f.valid.mean() > 0.8
    with pytest.raises(ValueError, match="n:"):
        geofeat.extract(frame, n=0)


def test_train_detector_command_writes_weights_chosen_over_both_counts(tiny, tmp_path, capsys):
    from geofeat.cli import main

    out = tmp_path / "gk.npz"
    assert main(["train-detector", "--data", str(tiny), "--val", str(tiny), "--out", str(out),
                 "--keypoints", "100", "200", "--steps", "20", "--hidden", "4", "--denoise", "2"]) == 0
    table = capsys.readouterr().out
    assert "(chosen)" in table and "| 100 |" in table and "| 200 |" in table
    model = load_geokey(out)
    assert model.nms_radius in (2.0, 3.0, 4.0, 5.0)
    assert model.denoise == 2.0  # trained on the filtered image, and detects on it
    with pytest.raises(SystemExit):  # argparse's usage error, naming --denoise
        main(["train-detector", "--data", str(tiny), "--val", str(tiny), "--out", str(out), "--denoise", "-1"])
    assert "--denoise" in capsys.readouterr().err
    assert len(geofeat.detect(geofeat.read_sequence(tiny / "a-deform").frame(0), 50, detector=f"geokey={out}")) > 0


def test_validation_tries_thresholds_without_the_detectors_warnings_about_frames(tiny):
    """choose_model tries score thresholds that no candidate of a frame may reach, and `geofeat
    train-detector` printed "geokey: no candidate reaches the score threshold" for every frame and
    setting tried: noise that read as a problem with the validation data."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, results, chosen = choose_model({"shipped": load_geokey()}, [tiny / "a-deform"], counts=(100,),
                                          radii=(3.0,), level_biases=(0.0,), thresholds=(99.0,), progress=False)
    assert results[("shipped, threshold 99", 3.0)][100]["n_ref"] == 0  # tried, and no frame kept a keypoint
    assert chosen == ("shipped", 3.0)
    said = [str(w.message) for w in caught]
    assert not [text for text in said if text.startswith(("geokey:", "sift:"))], said
    with pytest.warns(UserWarning, match="geokey: no candidate reaches the score threshold 99"):  # elsewhere: said
        detect_geokey(geofeat.read_sequence(tiny / "a-deform").frame(0), 100, threshold=99.0, min_fraction=0.0)


def test_train_detector_reports_once_the_validation_frames_the_chosen_model_leaves_empty(tiny, tmp_path,
                                                                                          monkeypatch):
    """With the detectors' warnings left out of validation, a validation frame that truly has no
    keypoint at the chosen setting is said once, naming the frames; a model that finds keypoints on
    every frame says nothing."""
    from dataclasses import replace

    import geofeat.train.detector as detector
    from geofeat.detectors.cues import CUE_NAMES

    x = np.random.default_rng(0).normal(size=(200, len(CUE_NAMES))).astype(np.float32)
    y = (x[:, 0] > 0).astype(np.float32)
    monkeypatch.setattr(detector, "collect", lambda *args, **kwargs: (x, y))
    monkeypatch.setattr(detector, "warn_if_not_held_out", lambda *args: None)
    scores = {"repeatability": 0.5, "ms": 0.5, "mma": 0.5, "hits": 10.0, "pairs": 10.0, "n_ref": 100.0}
    shipped = load_geokey()
    blind = replace(shipped, threshold=np.inf, min_fraction=0.0)  # keeps no keypoint on any frame
    for model, empty in ((blind, True), (shipped, False)):
        monkeypatch.setattr(detector, "choose_model", lambda *args, m=model, **kwargs:
                            (m, {("scorer", 3.0): {16: dict(scores)}}, ("scorer", 3.0)))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            detector.train_detector([tiny], [tiny], tmp_path / f"{empty}.npz", n=16, steps=5, progress=False,
                                    names=("--data", "--val"))
        said = [str(w.message) for w in caught]
        assert not [text for text in said if text.startswith("geokey:")], said
        reports = [text for text in said if "at the chosen setting" in text]
        if empty:
            assert len(reports) == 1, said
            assert reports[0].startswith("--val: 3 of the 3 validation frames have no GeoKey keypoint at the chosen "
                                         "setting (scorer, NMS 3 px): a-deform/"), reports
        else:
            assert reports == [], reports


# ---------------------------------------------------------------- audit of detection inputs
@pytest.mark.parametrize("n", [-1, 2.5, True])
def test_detect_geokey_refuses_a_bad_n(n):
    """n = -1 used to drop the last keypoint (order[:-1]) and 2.5 to fail inside numpy slicing."""
    with pytest.raises(ValueError, match="n:"):
        detect_geokey(geofeat.read_demo_frame(), n)


@pytest.mark.parametrize("option, value", [("nms_radius", float("nan")), ("nms_radius", float("inf")),
                                           ("nms_radius", -1.0), ("threshold", [1, 2]), ("threshold", "1"),
                                           ("min_fraction", "0.5"), ("min_fraction", True), ("denoise", -1.0),
                                           ("denoise", float("nan")), ("denoise", "2")])
def test_detect_geokey_options_must_be_numbers(option, value):
    """NaN and inf radii failed converting to int (inf an OverflowError); a list threshold was
    float()'s TypeError; strings and bools passed as numbers."""
    with pytest.raises(ValueError, match=option):
        detect_geokey(geofeat.read_demo_frame(), 10, **{option: value})


def test_a_suppression_radius_beyond_the_image_keeps_the_best_candidate_only():
    """A radius larger than the image diagonal used to ask OpenCV for a kernel of terabytes."""
    frame = geofeat.read_demo_frame()
    best = detect_geokey(frame, 1, nms_radius=0)
    one = detect_geokey(frame, 0, nms_radius=1e6, threshold=-np.inf)
    assert len(one) == 1
    np.testing.assert_array_equal(one.xy, best.xy)


def test_rewritten_weights_are_read_again(tmp_path):
    """load_geokey cached by path: weights retrained into the same file were ignored for the rest
    of the process (the old model's keypoints, silently)."""
    path = tmp_path / "w.npz"
    shipped = load_geokey()
    shipped.save(path)
    assert load_geokey(path).nms_radius == shipped.nms_radius != 5.0
    layer, bias = np.zeros((5, 1), np.float32), np.zeros(1, np.float32)  # a depth-cue layer: another size on disk
    GeoKeyModel(shipped.mean, shipped.std, shipped.linear, (layer,), (bias,), 5.0).save(path)
    again = load_geokey(path)
    assert again.uses_depth_cues and again.nms_radius == 5.0


def test_weights_path_that_is_a_folder_says_so(tmp_path):
    with pytest.raises(ValueError, match="is a folder"):
        geofeat.detect(geofeat.read_demo_frame(), 10, detector=f"geokey={tmp_path}")
    with pytest.raises(ValueError, match="is a folder"):
        load_geokey(tmp_path)


def test_an_npy_file_as_weights_is_a_clear_error_naming_it(tmp_path):
    """np.load gives an .npy file's array itself, which is no context manager: a bare TypeError
    ('numpy.ndarray' object does not support the context manager protocol) that named no file."""
    path = tmp_path / "single.npy"
    np.save(path, np.zeros(3))
    with pytest.raises(ValueError, match="single.npy.*not an .npz archive"):
        geofeat.detect(geofeat.read_demo_frame(), 10, detector=f"geokey={path}")


def test_depth_cue_layers_that_are_not_matrices_are_refused_on_load(tmp_path):
    """A (1, 5, 4) first layer chains through np.matmul by broadcasting, passed the load checks, and
    failed in the middle of detection with 'array is not broadcastable to correct shape', naming no
    file."""
    shipped = load_geokey()
    layers = (np.full((1, 5, 4), 0.01, np.float32), np.full((4, 1), 0.01, np.float32))
    biases = (np.zeros(4, np.float32), np.zeros(1, np.float32))
    path = tmp_path / "w3d.npz"
    GeoKeyModel(shipped.mean, shipped.std, shipped.linear, layers, biases, 3.0).save(path)
    with pytest.raises(ValueError, match="w3d.npz.*matrices"):
        geofeat.detect(geofeat.read_demo_frame(), 10, detector=f"geokey={path}")


def test_weights_for_other_cues_say_which_cue_differs(tmp_path):
    """Weights of a version with one more cue said 'cues ('level', 'log_eig_3', 'log_eig_7')...,
    expected ('level', 'log_eig_3', 'log_eig_7')...': the same names, so no hint of what differed."""
    arrays = dict(np.load(SHIPPED_WEIGHTS))
    arrays["cue_names"] = np.array(list(arrays["cue_names"]) + ["extra_cue"])
    path = tmp_path / "other_cues.npz"
    np.savez(path, **arrays)
    n = len(load_geokey().mean)
    with pytest.raises(ValueError, match=rf"other_cues.npz.*{n + 1} cues, expected {n}; cue {n} is 'extra_cue'"):
        load_geokey(path)


def test_an_empty_detector_name_is_not_the_default():
    """extract(detector="") used the descriptor's own detector, where detect(detector="") refuses it."""
    with pytest.raises(ValueError, match="detector"):
        geofeat.extract(geofeat.read_demo_frame(), 10, detector="", descriptor="geobit")


def test_extract_on_a_frame_without_keypoints_names_the_frame():
    """It used to end on "keypoints: the keypoint set is empty", an argument extract has not."""
    frame = geofeat.read_demo_frame()
    blank = geofeat.RGBDFrame(np.full(frame.shape, 0.5, np.float32), frame.depth, frame.K)
    with pytest.warns(UserWarning, match="geokey"), pytest.raises(ValueError, match="frame: no keypoints"):
        geofeat.extract(blank, 10, descriptor="geobit")


@pytest.mark.parametrize("k", [1, 2, 3])
def test_half_resolution_candidates_follow_a_rotated_frame(k):
    """cv2.pyrDown centres half-resolution pixel i on full-resolution pixel 2 i: mapping it to 2 i + 0.5
    put every half-resolution candidate 0.7 px off its corner, in the image's own (+x, +y) direction, so
    that the same corner in a rotated frame came back about 1 px away (full-resolution ones: 0 px)."""
    from geofeat.frame import rotate_points90

    frame = geofeat.read_demo_frame()
    turned = frame.rotated90(k)
    a, b = candidates(frame), candidates(turned)
    for level in (0, 1):
        mapped = rotate_points90(a.xy[a.level == level], frame.shape, k)
        dist, j = cKDTree(b.xy[b.level == level]).query(mapped)
        near = dist < 1.5
        offset = (b.xy[b.level == level][j[near]] - mapped[near]).mean(axis=0)
        assert near.sum() > 200, (level, near.sum())
        assert np.hypot(*offset) < 0.2, (level, offset)


def test_a_pair_without_target_keypoints_scores_zero_not_nan(tiny):
    """A target frame where the detector keeps no keypoint gave the pair an MS of NaN, which made its
    sequence's mean and the validation MS NaN (train-detector printed "nan"; `max` then chose among
    NaN at random), while the bench scores such a pair 0 and repeatability already counted it as 0."""
    from geofeat.train.detector import validation_scores

    def detector(frame, n):  # nothing on the last target frame
        k = geofeat.detect(frame, n, detector="sift")
        return k[:0] if frame.image.tobytes() == last else k

    seq = geofeat.read_sequence(tiny / "a-deform")
    last = seq.frame(seq.targets[-1]).image.tobytes()
    scores = validation_scores([tiny / "a-deform"], detector, 200, descriptor="orb")
    everyone = validation_scores([tiny / "a-deform"], lambda frame, n: geofeat.detect(frame, n, detector="sift"), 200,
                                 descriptor="orb")
    assert np.isfinite([scores["ms"], scores["mma"], scores["hits"]]).all()
    assert 0 < scores["ms"] < everyone["ms"]  # the other pair's MS averaged with a 0
    assert scores["repeatability"] < everyone["repeatability"]  # which repeatability already counted


def test_noise_level_measures_added_noise_and_ignores_shading():
    from geofeat.detectors.geokey import noise_level

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:240, 0:320].astype(np.float32)
    shading = 0.3 + 0.4 * x / 320 + 0.1 * np.sin(y / 40)  # smooth: the mask cancels it
    assert noise_level(shading) < 1e-3
    for sigma in (1 / 255, 5 / 255):
        assert noise_level(shading + rng.normal(0, sigma, shading.shape)) == pytest.approx(sigma, rel=0.1)
    assert noise_level(np.zeros((2, 50))) == 0.0


def test_denoising_before_detection_keeps_corners_under_image_noise():
    """Noise of a few grey levels moves 3 px corners: the same textured view with two draws of noise
    gave GeoKey keypoints found again less often than the edge-preserving filter's."""
    from geofeat.detectors.geokey import detection_image

    frame = render_flat(make_texture(3), Z0)
    rng = np.random.default_rng(1)

    def noisy():
        return frame.with_image(np.clip(frame.image + rng.normal(0, 6 / 255, frame.shape), 0, 1))

    a, b = noisy(), noisy()
    shipped = load_geokey()

    def found_again(denoise: float) -> float:
        ka = detect_geokey(a, 400, shipped, denoise=denoise, threshold=-np.inf)
        kb = detect_geokey(b, 400, shipped, denoise=denoise, threshold=-np.inf)
        return float(np.mean(cKDTree(kb.xy).query(ka.xy)[0] < 1.5))

    raw, filtered = found_again(0.0), found_again(4.0)
    assert filtered > raw + 0.05, (raw, filtered)
    denoised = detection_image(a, 4.0)
    assert denoised.depth is a.depth and denoised.K is a.K and denoised.shape == a.shape
    assert detection_image(a, 0.0) is a


def test_the_denoise_setting_travels_with_the_weights(tmp_path):
    from dataclasses import replace

    frame = geofeat.read_demo_frame()
    model = replace(load_geokey(), denoise=3.0)
    model.save(tmp_path / "d.npz")
    assert load_geokey(tmp_path / "d.npz").denoise == pytest.approx(3.0)
    np.testing.assert_array_equal(geofeat.detect(frame, 500, detector=f"geokey={tmp_path / 'd.npz'}").xy,
                                  geofeat.detect(frame, 500, detector="geokey", denoise=3.0).xy)
    old = dict(np.load(tmp_path / "d.npz"))
    del old["denoise"]  # weights written before the setting existed: no filter
    np.savez(open(tmp_path / "old.npz", "wb"), **old)
    assert load_geokey(tmp_path / "old.npz").denoise == 0.0


def test_depth_cues_of_non_square_pixels_measure_each_axis_in_its_own_footprints():
    """With fx = 1.2 fy the depth cues measured steps along y in x footprints (z / fx): a plane tilted
    by 74 degrees about the image x axis read a slope of 4.2 instead of tan 74 = 3.5, and a depth
    discontinuity (over 4 footprints) where there is none; the same camera rolled by a quarter turn
    (fx and fy swap) gave other slopes, curvatures and contours."""
    from geofeat.detectors.cues import cue_maps, depth_edge_distance

    H, W = 120, 160
    K = np.array([[1.2 * 300.0, 0, (W - 1) / 2], [0, 300.0, (H - 1) / 2], [0, 0, 1]])
    v = np.mgrid[0:H, 0:W][0].astype(np.float64)
    a = np.radians(74)
    # the plane through (0, 0, 1) tilted by a about the image x axis: Z = 1 + tan(a) Y
    depth = 1.0 / (1.0 - np.tan(a) * (v - K[1, 2]) / K[1, 1])
    depth[:, 120:] += 0.5  # a step behind the plane on the right
    frame = geofeat.RGBDFrame(make_texture(3, 256)[:H, :W].astype(np.float32), depth.astype(np.float32), K)
    maps = cue_maps(frame)
    assert maps["slope"][60, 60] == pytest.approx(np.tan(a), rel=0.03)
    edges = depth_edge_distance(frame.depth, K[0, 0], 4.0, fy=K[1, 1])
    assert edges[60, 60] >= 5  # the slope steepens to 76 degrees (4 footprints) 10 rows lower
    turned = cue_maps(frame.rotated90(1))  # the same camera rolled: fx and fy swap, the maps turn with the image
    inner = (slice(10, -10), slice(10, -10))
    for name in ("slope", "log_curv_2", "log_curv_6"):
        np.testing.assert_allclose(np.rot90(maps[name])[inner], turned[name][inner], rtol=1e-2, atol=5e-3,
                                   err_msg=name)
    # a step is flagged on its left or upper pixel: turned, it may sit one pixel over
    np.testing.assert_allclose(np.rot90(maps["log_edge_dist"]), turned["log_edge_dist"], atol=1.0)
