"""Public API behaviours found wrong in review: each test failed before its fix."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import geofeat
from geofeat.frame import roll_camera

K = np.array([[80.0, 0, 39.5], [0, 80.0, 29.5], [0, 0, 1]])


def _frame(colour: bool = True) -> geofeat.RGBDFrame:
    rng = np.random.default_rng(0)
    image = (rng.random((60, 80, 3) if colour else (60, 80)) * 255).astype(np.uint8)
    return geofeat.RGBDFrame(image, np.ones((60, 80), np.float32), K)


# ---------------------------------------------------------------- RGBDFrame.with_image
def test_with_image_reads_uint8_as_the_constructor_does():
    """frame.with_image(uint8 gray) kept the values 0-255 as the float image, which every stage
    reads as [0, 1]: SIFT then found no keypoint at all (the image clipped to white), GeoKey
    other ones, without a word."""
    frame = _frame()
    gray8 = np.clip(np.rint(frame.image * 255), 0, 255).astype(np.uint8)
    swapped = frame.with_image(gray8)
    assert swapped.image.dtype == np.float32
    np.testing.assert_array_equal(swapped.image, geofeat.RGBDFrame(gray8, frame.depth, frame.K).image)
    gray16 = gray8.astype(np.uint16) * 257
    np.testing.assert_allclose(frame.with_image(gray16).image, swapped.image, atol=1e-6)


@pytest.mark.parametrize("bad", [np.nan, 2.0, -0.5])
def test_with_image_refuses_values_the_constructor_refuses(bad):
    """with_image took NaN and floats outside [0, 1] (an image in 0-255 as floats) as they were."""
    frame = _frame()
    image = frame.image.copy()
    image[5, 5] = bad
    with pytest.raises(ValueError, match=r"^image: "):
        frame.with_image(image)


def test_with_image_keeps_its_own_copy():
    """with_image kept the caller's float32 array itself (the constructor copies): changing that
    array afterwards changed the frame's image."""
    frame = _frame()
    image = np.clip(frame.image * 0.5 + 0.2, 0, 1).astype(np.float32)
    swapped = frame.with_image(image)
    before = swapped.image.copy()
    image[:] = 0.0
    np.testing.assert_array_equal(swapped.image, before)


# ---------------------------------------------------------------- roll_camera
def test_roll_camera_turns_the_frames_own_gray_image():
    """roll_camera started from the colour image, so a frame from `with_image` (a filtered gray
    image, the colour kept for display) came back with the unfiltered gray image rolled, as
    rotated90 did before it was fixed; a frame whose gray is its colour's is unchanged."""
    frame = _frame()
    filtered = frame.with_image(np.clip(frame.image * 0.5 + 0.2, 0, 1))
    rolled, A = roll_camera(filtered, 30.0)
    H, W = frame.shape
    expected = cv2.warpAffine(filtered.image, A, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    np.testing.assert_allclose(rolled.image, expected, atol=1e-6)
    assert rolled.color is not None
    plain, A2 = roll_camera(frame, 30.0)  # the colour image's gray: as before
    colour = cv2.warpAffine(frame.color, A2, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    np.testing.assert_array_equal(plain.image, geofeat.RGBDFrame(colour, plain.depth, K).image)


# ---------------------------------------------------------------- viz.draw_matches
def test_draw_matches_takes_what_detect_and_match_return():
    """draw_matches(frame0, frame1, detect(...), detect(...), match(...)) was "TypeError: type
    Keypoints doesn't define __round__ method", and a Matches record for matches0 "'>=' not
    supported between instances of 'Matches' and 'int'"; the picture is the one of the arrays."""
    from geofeat.viz import draw_matches

    frame = _frame()
    xy0 = np.array([[10.0, 12.0], [40.0, 30.0], [70.0, 50.0]])
    xy1 = np.array([[12.0, 10.0], [41.0, 33.0]])
    m = geofeat.Matches(np.array([1, -1, 0]), np.array([1.0, np.inf, 2.0]))
    expected = draw_matches(frame, frame, xy0, xy1, m.matches0)
    kp0, kp1 = geofeat.as_keypoints(xy0), geofeat.as_keypoints(xy1)
    np.testing.assert_array_equal(draw_matches(frame, frame, kp0, kp1, m), expected)
    np.testing.assert_array_equal(draw_matches(frame, frame, kp0.to_cv(), kp1.to_cv(), m.matches0), expected)


# ---------------------------------------------------------------- RGBDFrame ==
def test_frames_compare_by_value():
    """frame0 == frame1 (and frames.index(frame), frame in frames) of two distinct frames was
    "ValueError: The truth value of an array with more than one element is ambiguous", from the
    dataclass's generated __eq__; hash(frame) named an ndarray, not the frame."""
    frame = _frame()
    same = geofeat.RGBDFrame(frame.color, frame.depth.copy(), frame.K.copy())
    other = frame.rotated90(2)
    assert frame == same and not frame != same
    assert frame != other and not frame == other
    assert [other, same].index(frame) == 1 and frame in [other, same]
    assert frame != "a frame"
    assert frame.with_image(frame.image * 0.5) != frame  # another gray image: another frame
    with pytest.raises(TypeError, match="RGBDFrame"):
        hash(frame)


def test_records_compare_by_value(tmp_path):
    """features == load_features(path) (a round trip's natural check), and == of two Keypoints or
    Matches, was "ValueError: The truth value of an array with more than one element is
    ambiguous", from the dataclasses' generated __eq__."""
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 256, (5, 16, 64), dtype=np.uint8)
    xy = rng.random((5, 2)) * 50
    features = geofeat.Features(xy, desc, np.array([1, 1, 0, 1, 1], bool), angles=np.zeros(5), sizes=np.full(5, np.nan))
    geofeat.save_features(tmp_path / "f.npz", features)
    assert geofeat.load_features(tmp_path / "f.npz") == features
    assert features != geofeat.Features(xy, desc, None, angles=np.zeros(5), sizes=np.full(5, np.nan))  # valid differs
    assert features != geofeat.Features(xy, desc, features.valid)  # no angles, sizes
    assert features != "features"
    kp = geofeat.as_keypoints(xy)  # NaN sizes and responses: still equal to itself, by value
    assert kp == geofeat.as_keypoints(xy.copy()) and kp != geofeat.as_keypoints(xy + 1)
    assert kp[[0, 1]] == kp[:2] and kp != kp[:2]
    m = geofeat.Matches([1, -1], [0.5, np.inf])
    geofeat.save_matches(tmp_path / "m.npz", m)
    assert geofeat.load_matches(tmp_path / "m.npz") == m and m != geofeat.Matches([1, 0], [0.5, 1.0])
    for record in (features, kp, m):
        with pytest.raises(TypeError, match="unhashable"):
            hash(record)


@pytest.mark.parametrize("matches0", [[True, False, True], [0.25, 0.9, 0.5], [np.nan, 1.0, -1.0], [-2, 0, 1]])
def test_matches_refuse_what_is_not_an_index(matches0):
    """Matches(matches0=a mask or scores) matched every keypoint to keypoint 0 or 1 without a word
    (True -> 1, 0.9 -> 0), NaN was "cannot convert float NaN to integer", and -2 passed for "no match"."""
    with pytest.raises(ValueError, match=r"^matches0: "):
        geofeat.Matches(matches0, np.zeros(3))


def test_matches_take_whole_floats():
    """Whole-number floats (an index array stored as float, -1 for none) are indices as before."""
    m = geofeat.Matches(np.array([2.0, -1.0, 0.0]), np.zeros(3))
    assert m.matches0.dtype == np.int64 and m.matches0.tolist() == [2, -1, 0]
    assert len(geofeat.Matches(np.zeros(0), np.zeros(0))) == 0


def test_roll_camera_names_an_angle_that_is_not_a_finite_number():
    """roll_camera(frame, nan) built a NaN rotation, put every pixel off the image and failed with
    "depth: every pixel is 0 (missing)", naming neither the angle nor the cause."""
    frame = geofeat.read_demo_frame()
    for angle in (float("nan"), float("inf"), "30", True):
        with pytest.raises(ValueError, match="angle_deg: expected a finite angle"):
            roll_camera(frame, angle)
    assert roll_camera(frame, np.float32(30.0))[0].shape == frame.shape


# ---------------------------------------------------------------- keypoint sizes
@pytest.mark.parametrize("name", ["sift", "orb", "brisk", "freak", "tfeat-sim", "dali"])
@pytest.mark.parametrize("size", [-8.0, 0.0, np.inf])
def test_descriptors_that_describe_at_the_keypoint_size_refuse_sizes_that_are_no_diameter(name, size):
    """A negative or zero keypoint size (cv2.KeyPoint() leaves 0) was described by SIFT, ORB, BRISK
    and FREAK at their smallest support (1 px) and an infinite one at the default 8 px, without a
    word; the image-patch nets named a 'radius_px' the user never gave. NaN stays "unknown"."""
    frame = _frame()
    xy = np.array([[40.0, 30.0], [30.0, 25.0]])
    descriptor = geofeat.make_descriptor(name)
    with pytest.raises(ValueError, match=rf"^keypoints: 1 keypoint size\(s\) are not positive finite diameters "
                                         rf"\(e.g. #1: {size:g}\); {name} describes at the keypoint's size"):
        descriptor.compute(frame, geofeat.Keypoints(xy, np.zeros(2), [8.0, size], np.zeros(2)))
    unknown = descriptor.compute(frame, geofeat.Keypoints(xy, np.zeros(2), [8.0, np.nan], np.zeros(2)))
    given = descriptor.compute(frame, geofeat.Keypoints(xy, np.zeros(2), [8.0, 8.0], np.zeros(2)))
    np.testing.assert_allclose(unknown.descriptors, given.descriptors, atol=1e-6)  # DaLI's threads: float sums


# ---------------------------------------------------------------- float descriptors of two methods
def test_l2_matching_of_descriptors_of_different_scales_is_warned_of():
    """SIFT's (N, 128) float descriptors (norm about 512) matched against GeoPatch's or an image-patch
    net's (N, 128, norm 1) passed every check (one dtype, one width): each SIFT keypoint's "nearest"
    unit descriptor was simply the one most aligned with it, and each unit descriptor's nearest SIFT
    one the one of smallest norm, without a word. Descriptors of one method, or one method at
    another contrast (3 times), are not warned of; invalid rows are not looked at."""
    from geofeat.matching import distance_matrix

    sift = geofeat.make_descriptor("sift").compute(geofeat.read_demo_frame(), np.array(
        [[x, y] for x in range(100, 540, 40) for y in range(100, 380, 40)], float))
    assert sift.valid.all() and 400 < np.median(np.linalg.norm(sift.descriptors, axis=1)) < 600
    unit = sift.descriptors / np.linalg.norm(sift.descriptors, axis=1, keepdims=True)  # as GeoPatch's are
    for call in (lambda: geofeat.match(sift, unit, mutual=True), lambda: distance_matrix(unit, sift.descriptors)):
        with pytest.warns(UserWarning, match=r"median norms of .* differ 5\d\d times: descriptors of two methods") as record:
            call()
        assert record[0].filename == __file__  # points at the caller
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        geofeat.match(sift, sift.descriptors * 3.0)
        distance_matrix(unit[:50], unit[50:])
        invalid = np.concatenate([unit, sift.descriptors])  # the SIFT rows marked invalid
        geofeat.match(geofeat.Features(np.zeros((len(invalid), 2)), invalid, np.arange(len(invalid)) < len(unit)), unit)


# ---------------------------------------------------------------- a transposed frame
def test_a_frame_of_transposed_arrays_is_warned_of():
    """Image and depth given as (W, H) arrays with the camera's K (a column-major reader, a stray .T):
    the principal point of a 4:3 camera then lies 17 % of the width from the centre, which the 20 %
    bound let through, and the frame was described mirrored, with a K that does not fit it, without a
    word; so was a K with cx and cy swapped. A portrait frame with its own K (`rotated90`) is no
    transposed one."""
    frame = geofeat.read_demo_frame()
    with pytest.warns(UserWarning, match=r"^K: principal point \(319.5, 239.5\) lies at the centre of a 640x480 image, "
                                         r"not of this 480x640 one: are the image and depth transposed"):
        geofeat.RGBDFrame(frame.color.transpose(1, 0, 2), frame.depth.T, frame.K)
    swapped = frame.K.copy()
    swapped[0, 2], swapped[1, 2] = frame.K[1, 2], frame.K[0, 2]  # cx and cy swapped: the same point, transposed
    with pytest.warns(UserWarning, match=r"transposed .*, or cx and cy swapped in K\?"):
        geofeat.RGBDFrame(frame.color, frame.depth, swapped)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        portrait = frame.rotated90(1)
        geofeat.RGBDFrame(portrait.color, portrait.depth, portrait.K)


@settings(max_examples=40, deadline=None)
@given(short=st.integers(32, 300), ratio=st.floats(1.0, 2.5))
def test_only_a_transposed_frame_is_warned_of_whatever_its_size(short, ratio):
    """For a frame of any size with its centred K: the frame itself gives no warning, and its transposed
    arrays are warned of as transposed when the sides differ by a quarter or more, and not when they differ
    by under 15 % (the principal points of the two then nearly coincide, and the K fits either; the bound
    lies at a fifth)."""
    H, W = short, int(round(short * ratio))
    f = float(max(H, W))
    K_own = np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])
    image = np.random.default_rng(short).integers(0, 256, (H, W), dtype=np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        geofeat.RGBDFrame(image, np.ones((H, W), np.float32), K_own)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        geofeat.RGBDFrame(image.T, np.ones((W, H), np.float32), K_own)
    transposed = [w for w in caught if "transposed" in str(w.message)]
    if W >= 1.25 * H:
        assert len(transposed) == 1
    elif W <= 1.15 * H:
        assert not transposed


# ---------------------------------------------------------------- depth in centimetres or decimetres
def test_a_frame_of_depth_farther_than_an_rgbd_camera_sees_is_warned_of(tmp_path):
    """Depth in centimetres of a scene nearer than 50 cm (median 40 "m"), or in decimetres, passed the
    50 m bound of millimetres and was described as a scene 10 or 100 times farther, every geodesic
    patch a few pixels wide, without a word; the readers warned of it (once per sequence), the frame
    did not. A sequence's frames are not warned of once more each."""
    from geofeat.inputs import DepthUnitsWarning

    demo = geofeat.read_demo_frame()
    metres = np.where(demo.depth > 0, 0.4, 0.0).astype(np.float32)
    with pytest.warns(DepthUnitsWarning, match=r"^depth: median 40 m is farther than an RGB-D camera sees .*; read as "
                                               r"centimetres 0.40 m"):
        geofeat.RGBDFrame(demo.color, metres * 100, demo.K)
    with pytest.warns(DepthUnitsWarning, match=r"^depth: median 9.77 m is farther than an RGB-D camera sees"):
        geofeat.RGBDFrame(demo.color, demo.depth * 10, demo.K)
    folder = tmp_path / "far"
    folder.mkdir()
    geofeat.write_intrinsics(folder / "intrinsics.xml", demo.K)
    for name in ("a-ref", "b"):
        geofeat.write_frame(folder, name, demo.color, demo.depth * 6)
    with pytest.warns(DepthUnitsWarning) as caught:
        seq = geofeat.read_sequence(folder)
        frames = [seq.frame("a-ref"), seq.frame("b"), geofeat.read_frame(
            folder / "b-rgb.png", folder / "b-depth.png", folder / "intrinsics.xml")]
    said = [str(w.message) for w in caught if w.category is DepthUnitsWarning]  # once by each reader
    assert len(said) == 2 and said[0].startswith(f"sequence {folder} ") and said[1].startswith(f"depth_path: {folder}")
    assert all(f.depth.max() == pytest.approx(6 * demo.depth.max(), rel=1e-3) for f in frames)  # a warning, no error
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        geofeat.RGBDFrame(demo.color, demo.depth * 4, demo.K)  # 3.9 m: an RGB-D camera's range


# ---------------------------------------------------------------- rotate_points90
def test_rotate_points90_takes_integer_quarter_turns_only():
    """rotate_points90(points, shape, 1.5) (or 0.5, 2.0) fell through every k == 0, 1, 2 test and turned
    the points by three quarter turns without a word, while frame.rotated90(1.5) was a TypeError."""
    from geofeat.frame import rotate_points90

    frame = _frame()
    xy = np.array([[10.0, 20.0], [79.0, 0.0]])
    for k in (1.5, 0.5, 2.0, "1", True):
        with pytest.raises(TypeError, match=r"^k: expected an integer number of quarter turns"):
            rotate_points90(xy, frame.shape, k)
    turned = frame.rotated90(1)
    moved = rotate_points90(xy, frame.shape, np.int64(5))  # numpy's integers, any sign: as rotated90 takes them
    np.testing.assert_array_equal(moved, rotate_points90(xy, frame.shape, -3))
    np.testing.assert_array_equal(turned.image[moved[:, 1].astype(int), moved[:, 0].astype(int)],
                                  frame.image[xy[:, 1].astype(int), xy[:, 0].astype(int)])


# ---------------------------------------------------------------- flags that are no bool
@pytest.mark.parametrize("flag", ["false", "no", 0.0, 1, None])
def test_flags_that_change_the_data_refuse_what_is_not_true_or_false(flag, tmp_path):
    """DepthConfig(constant="false") (a string from a config file) replaced the surface by a plane, the
    ablation, and simulate_sequence(kinect_noise="no") wrote noisy depth (recording kinect_noise: true),
    motion_blur="no" blurred the targets and overwrite="no" replaced an earlier simulation, all because
    the string reads as True in an `if`; 0.0, 1 and None were taken alike."""
    with pytest.raises(ValueError, match=r"^constant: expected True or False"):
        geofeat.DepthConfig(constant=flag)
    for name in ("kinect_noise", "motion_blur", "overwrite"):
        with pytest.raises(ValueError, match=rf"^{name}: expected True or False"):
            geofeat.simulate_sequence(tmp_path / "seq", n_frames=2, progress=False, preset="paper", **{name: flag})
        assert not (tmp_path / "seq").exists()
    assert geofeat.DepthConfig(constant=np.True_).constant is True


def test_read_sequence_names_its_python_argument_for_a_bad_depth_scale(tmp_path):
    """read_sequence(folder, depth_scale="0.001") said "--depth-scale: expected a positive number", an
    option of the command line, to a Python caller, who has none."""
    demo = geofeat.read_demo_frame()
    geofeat.write_intrinsics(tmp_path / "intrinsics.xml", demo.K)
    geofeat.write_frame(tmp_path, "a-ref", demo.color, demo.depth)
    for bad in ("0.001", -0.001, 1000.0):
        with pytest.raises(ValueError, match=r"^depth_scale: "):
            geofeat.read_sequence(tmp_path, depth_scale=bad)


def test_describer_refuses_a_single_name_string_and_an_unknown_profile():
    """`Describer("geobit", ...)` iterated the string ("unknown name 'g'"), and `profile="auto"` was a bare
    KeyError: both name their argument now."""
    from geofeat.descriptors.describer import Describer

    with pytest.raises(ValueError, match=r"names: expected a list of descriptor names such as \['geobit'\]"):
        Describer("geobit", 0.05)
    for profile in ("auto", "Kinect", "fast"):
        with pytest.raises(ValueError, match=rf"profile: expected one of kinect, quantised, clean.*got '{profile}'"):
            Describer(("geobit",), 0.05, profile)
    assert Describer(("geobit",), 0.05, "quantised").descriptors["geobit"].depth_config.mesh_scale == 0.5


def test_a_baselines_size_factor_and_a_bootstrap_level_in_percent_are_refused():
    """`OpenCVDescriptor("sift", size_factor=-1)` described every keypoint at 1 px without a word, and
    `bootstrap_interval(x, level=95)` failed inside numpy's quantile, naming no argument."""
    from geofeat.apps.retrieval import bootstrap_interval
    from geofeat.descriptors.baselines import OpenCVDescriptor

    for factor in (-1.0, 0.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="sift: size_factor"):
            OpenCVDescriptor("sift", size_factor=factor)
    assert OpenCVDescriptor("sift", size_factor=2.0).size_factor == 2.0
    with pytest.raises(ValueError, match=r"level \(a fraction, 0.95 for 95 %\)"):
        bootstrap_interval(np.ones(10), level=95)
    low, high = bootstrap_interval(np.arange(10.0), level=0.9)
    assert low < 4.5 < high


def test_retrieval_refuses_a_fractional_seed_and_no_neighbours():
    """`vocabulary(..., seed=2.5)` drew the words of seed 2 without a word, and `search(..., k=0)` returned
    no neighbours (every accuracy of them 0)."""
    from geofeat.apps.retrieval import search, vocabulary

    rng = np.random.default_rng(0)
    descriptors = rng.standard_normal((40, 8)).astype(np.float32)
    with pytest.raises(ValueError, match="seed: expected a whole number >= 0, got 2.5"):
        vocabulary(descriptors, 4, seed=2.5)
    assert len(vocabulary(descriptors, 4, seed=np.int64(2))) == 4
    with pytest.raises(ValueError, match="k: expected a whole number >= 1, got 0"):
        search(rng.random((3, 5)), rng.random((6, 5)), k=0)
    assert search(rng.random((3, 5)), rng.random((6, 5)), k=2)[0].shape == (3, 2)


def test_keypoints_off_the_image_that_fit_as_row_column_pairs_say_so():
    """Keypoints given as (row, column), as np.argwhere and scikit-image return them, were refused as
    off the image with no word on why; when every one fits the image once swapped, the error says so."""
    from geofeat.keypoints import as_keypoints

    rows_cols = np.array([[10.0, 20.0], [100.0, 600.0], [470.0, 630.0]])  # (row, col) on a 640 x 480 image
    with pytest.raises(ValueError, match=r"off the 640x480 image.*\(row, column\) pairs.*xy\[:, ::-1\]"):
        as_keypoints(rows_cols, (480, 640))
    assert len(as_keypoints(rows_cols[:, ::-1], (480, 640))) == 3
    with pytest.raises(ValueError, match=r"off the 640x480 image, e.g. #0 at \(700.0, 10.0\)$"):
        as_keypoints(np.array([[700.0, 10.0], [5.0, 600.0]]), (480, 640))  # off both ways: no hint


def test_features_of_two_descriptors_are_not_matched_and_files_keep_the_method(tmp_path):
    """ORB's and BRAND's descriptors are both (N, 32) uint8 and were matched without a word (so were
    SIFT's and GeoPatch's (N, 128) float32, warned of only by their norms). Features now record the
    descriptor that computed them; files keep it; `match` refuses two methods."""
    from geofeat.features import Features, load_features, save_features

    frame = geofeat.read_demo_frame()
    kps = geofeat.detect(frame, 64, detector="sift")
    orb = geofeat.make_descriptor("orb").compute(frame, kps)
    brand = geofeat.make_descriptor("brand").compute(frame, kps)
    assert (orb.method, brand.method, geofeat.GeoBit().compute(frame, kps).method) == ("orb", "brand", "geobit")
    with pytest.raises(ValueError, match=r"descriptors of two methods \(orb and brand\)"):
        geofeat.match(orb, brand)
    assert (geofeat.match(orb, orb).matches0[orb.valid] >= 0).all()
    bare = Features(orb.keypoints, brand.descriptors, brand.valid)  # no method recorded: not checked
    assert geofeat.match(orb, bare).matches0.shape == (len(orb),)
    for name in ("f.npz", "f.h5"):
        save_features(tmp_path / name, brand, name="cloud_1")
        assert load_features(tmp_path / name, "cloud_1").method == "brand"
    with pytest.raises(ValueError, match="method: expected a descriptor name or None"):
        Features(orb.keypoints, orb.descriptors, orb.valid, method="")
