"""An outside review of the public Python API for silently wrong results: each test is a call that
returned a plausible-looking wrong answer (or an IndexError from deep inside) and now raises or
warns, naming the argument."""

from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest

import geofeat
from geofeat.frame import RGBDFrame, rotate_points90
from geofeat.groundtruth.landmarks import inside_hull, robust_landmark_tps
from geofeat.groundtruth.sources import GroundTruth
from geofeat.io import read_landmarks, write_frame, write_intrinsics, write_landmarks
from geofeat.scoring import correct_matches, ground_truth_pairs, score_detect, score_landmarks
from geofeat.tps import fit_tps, solve_batch

K_VGA = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])


def _image(shape=(480, 640), seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape + (3,), dtype=np.uint8)


# ---------------------------------------------------------------- scoring (geofeat.scoring)
def test_scoring_refuses_transposed_points_instead_of_reshaping_them():
    """ground_truth_pairs(ref.T, tgt.T) reshaped the (2, N) arrays of x's then y's into N bogus points
    and returned 50 'pairs'; an (N, 3) array (x, y, score) gave 25 pairs of mixed-up coordinates."""
    rng = np.random.default_rng(0)
    ref = rng.uniform(0, 400, (50, 2))
    tgt = ref + rng.normal(0, 0.5, ref.shape)
    assert len(ground_truth_pairs(ref, tgt)) == 50
    with pytest.raises(ValueError, match=r"ref_xy: expected shape \(N, 2\) of \(x, y\) pixels, got \(2, 50\)"):
        ground_truth_pairs(ref.T, tgt.T)
    with pytest.raises(ValueError, match=r"ref_xy: expected shape \(N, 2\) of \(x, y\) pixels, got \(50, 3\)"):
        ground_truth_pairs(np.c_[ref, np.ones(50)], tgt)
    with pytest.raises(ValueError, match=r"tgt_in_ref: expected shape \(N, 2\)"):
        correct_matches(ref, tgt.T)
    with pytest.raises(ValueError, match="tgt_in_ref: expected one point per match, 10 like ref_xy, got 50"):
        correct_matches(ref[:10], tgt)  # was numpy's "operands could not be broadcast"
    assert ground_truth_pairs(np.zeros((0, 2)), []).shape == (0, 2)  # empty sets stay fine


def test_score_detect_checks_the_matches_against_the_keypoint_counts():
    """n_ref other than len(matches0) gave MS 5.0; a shorter matches0 or a `Matches` record raised a bare
    IndexError; (2, M) pairs (transposed) scored 0 hits without a word."""
    ref = np.random.default_rng(1).uniform(0, 400, (50, 2))
    pairs = ground_truth_pairs(ref, ref + 0.5)
    m = np.arange(50)
    assert score_detect(m, pairs, 50, 50).ms == 1.0
    assert score_detect(geofeat.Matches(m, np.zeros(50)), pairs, 50, 50).ms == 1.0  # a Matches reads as matches0
    with pytest.raises(ValueError, match=r"matches0: expected \(n_ref=10,\) integer indices .* got int64 shape \(50,\)"):
        score_detect(m, pairs, 10, 50)
    with pytest.raises(ValueError, match=r"matches0: expected \(n_ref=50,\) .* shape \(20,\)"):
        score_detect(m[:20], pairs, 50, 50)
    with pytest.raises(ValueError, match=r"matches0: expected target indices in \[0, n_tgt=30\) or -1"):
        score_detect(m, pairs, 50, 30)
    with pytest.raises(ValueError, match=r"gt_pairs: expected \(M, 2\) integer pairs .* shape \(2, 50\)"):
        score_detect(m, pairs.T, 50, 50)
    with pytest.raises(ValueError, match=r"gt_pairs: indices must lie in \[0, n_ref=50\) and \[0, n_tgt=50\)"):
        score_detect(m, pairs + [0, 60], 50, 50)
    assert score_detect(np.zeros(0, np.int64), np.zeros((0, 2), np.int64), 0, 5).ms == 0.0


def test_score_landmarks_refuses_a_match_index_past_the_targets():
    """An index past the target landmarks was clipped to the last one and, when that one had the
    query's id, counted as a hit: matches0 [0, 1, 2, 3, 9] scored 5/5."""
    ids = np.arange(5)
    assert score_landmarks(np.arange(5), ids, ids).hits == 5
    with pytest.raises(ValueError, match=r"matches0: expected target indices in \[0, len\(tgt_ids\)=5\) or -1"):
        score_landmarks(np.array([0, 1, 2, 3, 9]), ids, ids)
    with pytest.raises(ValueError, match=r"matches0: expected \(len\(ref_ids\)=5,\)"):
        score_landmarks(np.array([0, 1, 2]), ids, ids)  # was a numpy broadcasting error


# ---------------------------------------------------------------- thin-plate spline (geofeat.tps)
def test_a_repeated_control_point_with_its_own_destination_is_fitted():
    """The docstring says a point repeated with the same destination is fine, and it was, when LAPACK's
    LU noticed the singular system; when it did not (these points), fit_tps got round-off of 1e15 from
    np.linalg.solve and refused the points as 'repeated ... with different destinations'.
    solve_batch returned ok=True with weights of 1e28 for a repeat with two destinations."""
    rng = np.random.default_rng(1)
    src = rng.random((10, 2)) * 500
    dst = src + rng.normal(0, 2, (10, 2))
    s, d = np.vstack([src, src[:1]]), np.vstack([dst, dst[:1]])
    np.testing.assert_allclose(fit_tps(s, d)(s), d, atol=1e-6)
    with pytest.raises(ValueError, match="degenerate control points"):
        fit_tps(s, np.vstack([dst, dst[:1] + 3]))
    for seed in (1, 2, 5):  # the seeds on which LU does not notice
        rng = np.random.default_rng(seed)
        a = rng.random((10, 2))
        b = a + rng.normal(0, 0.01, a.shape)
        batch_src, batch_dst = np.vstack([a, a[:1]])[None], np.vstack([b, b[:1] + 0.05])[None]
        assert solve_batch(batch_src, batch_dst, 0.0)[2].tolist() == [False]
        assert solve_batch(batch_src, batch_dst, 1e-3)[2].tolist() == [True]  # smoothing has a solution


# ---------------------------------------------------------------- frames (geofeat.RGBDFrame)
def test_a_frame_warns_of_intrinsics_made_for_another_resolution():
    """A 640x480 K on a frame downsampled to 320x240 (principal point at the bottom-right corner), or a
    320x240 K on a 640x480 frame, was taken without a word: every patch then has the wrong size and shape."""
    depth = np.ones((480, 640), np.float32)
    with pytest.warns(UserWarning, match=r"K: principal point \(319.5, 239.5\) lies far from the centre of the "
                                         r"320x240 image .* intrinsics for another image size"):
        RGBDFrame(_image((240, 320)), depth[::2, ::2], K_VGA)
    half = K_VGA.copy()
    half[:2] /= 2
    with pytest.warns(UserWarning, match="principal point .* far from the centre of the 640x480 image"):
        RGBDFrame(_image(), depth, half)
    off = K_VGA.copy()
    off[0, 2] = 1000.0
    with pytest.warns(UserWarning, match=r"principal point \(1000, 239.5\)"):  # off the image, as a crop's may be
        RGBDFrame(_image(), depth, off)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frame = RGBDFrame(_image(), depth, K_VGA)
        for k in (1, 2, 3):
            frame.rotated90(k)
        crop = K_VGA - [[0, 0, 160], [0, 0, 120], [0, 0, 0]]  # the central 320x240 with its shifted K
        RGBDFrame(_image((240, 320)), depth[120:360, 160:480], crop)
        geofeat.read_demo_frame()


def test_a_frame_warns_of_a_nearly_black_uint16_or_float_image():
    """8-bit values in a uint16 array (or floats divided by 255 twice) were read as a gray image with
    its brightest pixel at 0.4 %: SIFT found no keypoint on it, without a word."""
    image, depth = _image(), np.ones((480, 640), np.float32)
    with pytest.warns(UserWarning, match="image: nearly black .* brightest value is 255 of 65535: 8-bit values "
                                         "in a uint16 array"):
        frame = RGBDFrame(image.astype(np.uint16), depth, K_VGA)
    assert frame.image.max() < 0.004  # the reading itself is unchanged (uint16 is 0-65535)
    with pytest.warns(UserWarning, match="image: nearly black .* divided by 255 twice"):
        RGBDFrame(image / 255.0 / 255.0, depth, K_VGA)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for fine in (image, image.astype(np.uint16) * 257, image / 255.0, np.zeros((480, 640))):
            RGBDFrame(fine, depth, K_VGA)


def test_sift_warns_when_it_finds_no_keypoint_as_geokey_does():
    """`extract`'s docstring says detect warns and returns an empty set on a frame without texture: GeoKey
    did, SIFT returned an empty set without a word (as on the nearly black uint16 frame above), and
    describing or matching it gave empty results that look like a bad descriptor."""
    depth = np.ones((480, 640), np.float32)
    blank = RGBDFrame(np.full((480, 640), 0.5, np.float32), depth, K_VGA)
    for keypoint_set in ("unique", "protocol"):
        with pytest.warns(UserWarning, match="sift: no keypoint"):
            assert len(geofeat.detect(blank, 10, detector="sift", keypoint_set=keypoint_set)) == 0
    no_depth = RGBDFrame(_image(), np.pad(np.ones((480, 2), np.float32), ((0, 0), (0, 638))), K_VGA)
    with pytest.warns(UserWarning, match="sift: no keypoint with depth under it"):
        assert len(geofeat.detect(no_depth, 10, detector="sift")) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(geofeat.detect(RGBDFrame(_image(), depth, K_VGA), 10, detector="sift")) == 10


# ---------------------------------------------------------------- geodesic patches and descriptors
def test_patches_and_meshes_of_another_frame_of_the_same_size_are_refused():
    """GeoBit/GeoPatch `compute(frame, kps, patches=...)` checked the patches' keypoints and radius, not
    their frame: the patches of the frame given to its 180-degree rotation (same size, same keypoints on
    the image) described the first frame without a word; so did `polar_patches(frame, kps, mesh=...)`
    with the rotated frame's mesh, which was checked for its size only."""
    frame = geofeat.read_demo_frame()
    turned = frame.rotated90(2)
    xy = np.array([[300.0, 250.0], [350.0, 200.0], [250.0, 300.0]])
    patches = geofeat.polar_patches(frame, xy)
    mesh = geofeat.build_mesh(frame)
    for descriptor in (geofeat.GeoBit(), geofeat.GeoPatch()):
        assert descriptor.compute(frame, xy, patches=patches).valid.all()
        assert descriptor.compute(geofeat.read_demo_frame(), xy, patches=patches).valid.all()  # an equal copy
        with pytest.raises(ValueError, match="patches: computed on another frame"):
            descriptor.compute(turned, xy, patches=patches)
    np.testing.assert_array_equal(geofeat.polar_patches(frame, xy, mesh=mesh).values, patches.values)
    with pytest.raises(ValueError, match="mesh: built from another frame"):
        geofeat.polar_patches(turned, xy, mesh=mesh)
    with pytest.raises(ValueError, match="mesh: built from another frame"):
        geofeat.heat_polar_patches(turned, xy[:1], mesh=mesh)


# ---------------------------------------------------------------- ground truth helpers
def _landmark_sequence(folder):
    """Two 160x120 frames, the target the reference shifted by 3 px, 20 landmarks."""
    K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
    folder.mkdir()
    write_intrinsics(folder / "intrinsics.xml", K)
    gx, gy = np.meshgrid(np.linspace(20, 130, 5), np.linspace(20, 100, 4))
    lm = np.stack([gx.ravel(), gy.ravel()], 1)
    for i, name in enumerate(("frame-000-master", "frame-001")):
        write_frame(folder, name, _image((120, 160), seed=i), np.ones((120, 160)))
        write_landmarks(folder / f"{name}.csv", np.arange(len(lm)), lm + [3 * i, 0], np.ones(len(lm), bool))
    return geofeat.read_sequence(folder)


def test_ground_truth_helpers_refuse_transposed_points(tmp_path):
    """GroundTruth.map, inside_hull, robust_landmark_tps and rotate_points90 reshaped a (2, N) array into
    N points made of x's then y's and answered for those."""
    seq = _landmark_sequence(tmp_path / "seq")
    truth = GroundTruth(seq, None)
    xy = np.array([[50.0, 40.0], [60.0, 50.0], [70.0, 55.0]])
    mapped, valid = truth.map("frame-001", xy)
    np.testing.assert_allclose(mapped[valid], xy[valid] - [3, 0], atol=1e-6)
    with pytest.raises(ValueError, match=r"xy: expected shape \(N, 2\) of \(x, y\) pixels, got \(2, 3\)"):
        truth.map("frame-001", xy.T)
    ids, lm, _ = seq.landmarks(0)
    with pytest.raises(ValueError, match=r"xy: expected shape \(N, 2\)"):
        inside_hull(lm, xy.T)
    with pytest.raises(ValueError, match=r"src: expected shape \(N, 2\)"):
        robust_landmark_tps(lm.T, lm.T + 1, (160, 120))
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 2\)"):
        rotate_points90(xy.T, (120, 160), 1)


def test_a_landmark_csv_with_a_byte_order_mark_is_read_as_one_without():
    """A spreadsheet's UTF-8 csv starts with a byte-order mark: without a header line its first landmark
    ('\\ufeff0,...') did not parse as numbers, passed for the header and was dropped without a word."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "a.csv"
        path.write_text("\ufeff0,1,2,1\n1,2,3,1\n", encoding="utf-8")
        with pytest.raises(ValueError, match="the first line '0,1,2,1' is a landmark, not a header"):
            read_landmarks(path)
        path.write_text("\ufeffid,x,y,valid\n0,1,2,1\n1,2,3,1\n", encoding="utf-8")
        ids, xy, visible = read_landmarks(path)
        assert ids.tolist() == [0, 1] and visible.all()


# ---------------------------------------------------------------- tracking (geofeat.apps.tracking)
def test_ransac_counts_that_fit_nothing_are_refused():
    """iterations=0, refinements=0 or max_centres < 4 tried no hypothesis, or fitted through one centre,
    and reported 'fit failed' (warp None) for matches that fit: the caller tunes on a false failure."""
    from geofeat.apps.tracking import fit_tps_ransac, refit_on_inliers

    rng = np.random.default_rng(1)
    src = rng.random((60, 2)) * 400
    dst = src * 1.1 + 5 + rng.normal(0, 0.5, src.shape)
    assert fit_tps_ransac(src, dst).ok and fit_tps_ransac(src, dst, max_centres=4).ok
    for kw, message in ((dict(iterations=0), "iterations: expected a whole number >= 1, got 0"),
                        (dict(refinements=0), "refinements: expected a whole number >= 1, got 0"),
                        (dict(max_centres=1), "max_centres: expected a whole number >= 4, got 1"),
                        (dict(min_inliers=2.5), "min_inliers: expected a whole number >= 0, got 2.5")):
        with pytest.raises(ValueError, match=message):
            fit_tps_ransac(src, dst, **kw)
    with pytest.raises(ValueError, match="refinements: expected a whole number >= 1"):
        refit_on_inliers(src, dst, np.ones(60, bool), refinements=0)


def test_the_main_containers_print_a_summary_not_their_arrays():
    """Printing a frame, keypoints, patches, features or matches (the README's examples do) gives one
    line with their counts and units; the dataclasses' own reprs dumped every array."""
    import numpy as np

    import geofeat

    frame = geofeat.read_demo_frame()
    kps = geofeat.detect(frame, 300, detector="sift")
    patches = geofeat.polar_patches(frame, kps)
    feats = geofeat.extract(frame, 300)
    matches = geofeat.match(feats, feats)
    texts = [repr(x) for x in (frame, kps, patches, feats, matches)]
    assert all("\n" not in t and len(t) < 160 and "array" not in t for t in texts), texts
    assert texts[0].startswith("RGBDFrame(640x480") and " m, " in texts[0]
    assert f"{len(kps)} keypoints" in texts[1] and " px" in texts[1]
    assert f"{int(patches.valid.sum())} valid" in texts[2] and "m)" in texts[2]
    assert f"descriptors {tuple(feats.descriptors.shape)} {feats.descriptors.dtype}" in texts[3]
    assert f"{int((matches.matches0 >= 0).sum())} matched" in texts[4]
    assert repr(geofeat.Keypoints(np.zeros((0, 2)), [], [], [])) == "Keypoints(0 keypoints)"


def test_patches_of_a_frame_with_another_image_are_refused():
    """The patches' `source` held the frame's depth and intrinsics only: the patches of a frame given
    with another image on the same depth (`frame.with_image(filtered)`, or a still camera's next frame)
    passed `compute(..., patches=...)`, and GeoBit and GeoPatch described the first image's intensities
    under the second frame's name without a word."""
    frame = geofeat.read_demo_frame()
    other = frame.with_image(1.0 - frame.image)
    xy = np.array([[300.0, 250.0], [350.0, 200.0], [250.0, 300.0]])
    patches = geofeat.polar_patches(frame, xy)
    heat = geofeat.heat_polar_patches(frame, xy[:1])
    for descriptor in (geofeat.GeoBit(), geofeat.GeoPatch()):
        assert descriptor.compute(frame.with_image(frame.image), xy, patches=patches).valid.all()  # equal image
        with pytest.raises(ValueError, match="patches: computed on another frame"):
            descriptor.compute(other, xy, patches=patches)
        with pytest.raises(ValueError, match="patches: computed on another frame"):
            descriptor.compute(other, xy[:1], patches=heat)
    own = geofeat.GeoBit().compute(other, xy, patches=geofeat.polar_patches(other, xy))
    assert own == geofeat.GeoBit().compute(other, xy)


def test_extract_refuses_a_radius_for_a_descriptor_without_one():
    """`geofeat.extract(frame, descriptor="orb", radius=0.05)` passed the radius to `make_descriptor`,
    which gives it only to the descriptors on geodesic patches: ORB described at its own size and the
    radius was ignored without a word (so was a depth profile)."""
    frame = geofeat.read_demo_frame()
    for options in ({"radius": 0.05}, {"depth_config": "clean"}, {"radius": 0.05, "depth_config": "kinect"}):
        with pytest.raises(ValueError, match=f"{next(iter(options))}: orb has no geodesic patch"):
            geofeat.extract(frame, 10, descriptor="orb", **options)
    assert len(geofeat.extract(frame, 10, descriptor="ORB", depth_config="auto")) == 10  # the defaults pass
    assert len(geofeat.extract(frame, 10, descriptor="orb", radius=None, depth_config=None)) == 10
    assert geofeat.extract(frame, 10, descriptor="geobit", radius=0.05, depth_config="kinect").descriptors.shape == (10, 16, 64)


# ---------------------------------------------------------------- frames 1 pixel high or wide
@functools.lru_cache(maxsize=None)
def _descriptor(name: str):
    return geofeat.make_descriptor(name, **({"progress": False} if name == "dali" else {}))


def _tiny_frame(H: int, W: int) -> RGBDFrame:
    """A textured (H, W) frame on a plane 1 m away, with a focal length of 0.9 times its longer side."""
    colour = (np.random.default_rng(H * 1000 + W).random((H, W, 3)) * 255).astype(np.uint8)
    f = 0.9 * max(H, W)
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    return RGBDFrame(colour, np.ones((H, W), np.float32), K)


@pytest.mark.parametrize("name", geofeat.descriptors.available_descriptors())
def test_every_descriptor_marks_the_keypoints_of_a_frame_one_pixel_high_or_wide_invalid_with_a_warning(name):
    """ORB on a 1 x 640, 640 x 1 or 1 x 1 frame failed with a raw OpenCV assertion ("inv_scale_x > 0" in
    its pyramid); SIFT, DAISY, DaLI and the image-patch nets called descriptors of the border pixels
    replicated across the frame valid, GeoBit and GeoPatch patches walked on a surface made up from one
    row of depth. Every descriptor now gives a well-formed result with every keypoint invalid (zero
    rows) and a warning, as for a frame without texture; `extract` refuses the frame as it refuses one
    without texture (the detectors warn and find nothing). A 2 x 2 frame is described as before."""
    descriptor = _descriptor(name)
    for H, W in ((1, 640), (640, 1), (1, 1)):
        frame = _tiny_frame(H, W)
        xy = np.array([[(W - 1) / 2, (H - 1) / 2], [0.0, 0.0]])
        with pytest.warns(UserWarning, match=rf"^{name}: the {W}x{H} frame is under 2 pixels high or wide"):
            features = descriptor.compute(frame, xy)
        assert features.keypoints.shape == (2, 2) and features.descriptors.shape[0] == 2
        assert features.valid.dtype == bool and not features.valid.any()
        assert not np.asarray(features.descriptors).any()
    with pytest.warns(UserWarning, match="no keypoint|no candidate"), \
            pytest.raises(ValueError, match="frame: no keypoints detected"):
        geofeat.extract(_tiny_frame(1, 640), 10, descriptor=name)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*pixels high or wide")
        features = descriptor.compute(_tiny_frame(2, 2), np.array([[0.5, 0.5]]))
    assert features.descriptors.shape[0] == 1 and features.valid.shape == (1,)
