"""OpenCV baselines on given keypoints: shapes, dropped keypoints, and that SIFT's angle helps."""

import cv2
import numpy as np
import pytest

import geofeat
from geofeat.descriptors.baselines import BASELINES, OpenCVDescriptor, orb_level, sift_octave
from geofeat.keypoints import Keypoints, detect, to_uint8
from geofeat.matching import match


def rotated_pair(angle_deg: float = 45.0):
    """The Kinect frame's gray image and a copy rotated about the image centre (depth constant:
    the baselines read only the image). Returns frames and the 2x3 affine map of the rotation."""
    frame = geofeat.read_demo_frame()
    H, W = frame.shape
    A = cv2.getRotationMatrix2D(((W - 1) / 2, (H - 1) / 2), angle_deg, 1.0)
    img = cv2.warpAffine(frame.image, A, (W, H), flags=cv2.INTER_LINEAR)
    depth = np.ones((H, W), np.float32)
    return geofeat.RGBDFrame(frame.image, depth, frame.K), geofeat.RGBDFrame(img, depth, frame.K), A


@pytest.fixture(scope="module")
def pair():
    f0, f1, A = rotated_pair(45.0)
    k0 = detect(f0, 400, detector="sift", require_depth=False, border_px=40)
    # the same physical points in the rotated image, with SIFT's angle rotated consistently
    xy1 = k0.xy @ A[:, :2].T + A[:, 2]
    inside = (xy1[:, 0] > 40) & (xy1[:, 0] < 600) & (xy1[:, 1] > 40) & (xy1[:, 1] < 440)
    k0 = k0[inside]
    # OpenCV angles are clockwise on screen; a counter-clockwise image rotation by 45 deg subtracts 45
    k1 = Keypoints(xy1[inside], (k0.angles - 45.0) % 360, k0.sizes, k0.responses)
    return f0, f1, k0, k1


@pytest.mark.parametrize("name", BASELINES)
def test_baseline_shapes_and_validity(name, pair):
    f0, _, k0, _ = pair
    F = OpenCVDescriptor(name).compute(f0, k0)
    assert F.descriptors.shape[0] == len(k0) and F.valid.mean() > 0.7
    assert (F.descriptors[~F.valid] == 0).all()
    np.testing.assert_array_equal(F.keypoints, k0.xy)


def test_dropped_keypoints_are_invalid():
    frame = geofeat.read_demo_frame()
    F = OpenCVDescriptor("orb").compute(frame, np.array([[2.0, 2.0], [320.0, 240.0]]))
    assert F.valid.tolist() == [False, True]


def test_daisy_on_the_first_pixel_row_or_column_is_invalid_not_an_opencv_error():
    """(-0.3, 10) lies on the image (pixel 0 spans [-0.5, 0.5)); OpenCV's DAISY asserted x >= 0."""
    frame = geofeat.read_demo_frame()
    xy = np.array([[-0.3, 240.0], [320.0, -0.5], [0.0, 0.0], [320.0, 240.0]])
    F = OpenCVDescriptor("daisy").compute(frame, xy)
    assert F.valid.tolist() == [False, False, True, True]
    assert (F.descriptors[:2] == 0).all()


@pytest.mark.parametrize("name", ["orb", "daisy", "sift"])
def test_sift_angle_helps_under_rotation(name, pair):
    """Descriptors that take the given angle match a 45 deg rotated copy better with it than without.
    (BRISK and FREAK estimate their own orientation, so the given angle does not change them.)"""
    f0, f1, k0, k1 = pair

    def correct(use_angle):
        d = OpenCVDescriptor(name, use_angle=use_angle)
        m = match(d.compute(f0, k0), d.compute(f1, k1))
        return (m.matches0 == np.arange(len(k0))).mean()

    with_angle, without = correct(True), correct(False)
    assert with_angle > without + 0.2, (with_angle, without)


@pytest.mark.parametrize("name", ["brisk", "freak"])
def test_own_orientation_baselines_are_rotation_invariant(name, pair):
    f0, f1, k0, k1 = pair
    d = OpenCVDescriptor(name)
    m = match(d.compute(f0, k0), d.compute(f1, k1))
    assert (m.matches0 == np.arange(len(k0))).mean() > 0.5


def test_unknown_baseline():
    with pytest.raises(ValueError, match="unknown"):
        OpenCVDescriptor("surf3000")


def test_baselines_that_use_the_given_angle_warn_on_unoriented_keypoints():
    import warnings

    frame = geofeat.read_demo_frame()
    geokey = geofeat.detect(frame, 50)  # the default detector gives no orientation
    with pytest.warns(UserWarning, match="angle 0"):
        geofeat.make_descriptor("orb").compute(frame, geokey)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        geofeat.make_descriptor("orb").compute(frame, geofeat.detect(frame, 50, detector="sift"))  # oriented: quiet
        geofeat.make_descriptor("freak").compute(frame, geokey)  # FREAK estimates its own orientation


@pytest.mark.parametrize("name", ["orb", "daisy", "sift"])
def test_angles_in_radians_warn(name, pair):
    """Keypoint angles in radians (scikit-image's ORB orientations, np.arctan2) were read as degrees:
    each patch turned by a 57th of its angle, and the descriptor lost its rotation invariance without
    a word. They warn now; SIFT's degrees, and BRISK (which estimates its own angle), stay quiet."""
    import warnings

    f0, _, k0, _ = pair
    radians = Keypoints(k0.xy, np.radians(k0.angles), k0.sizes, k0.responses)
    with pytest.warns(UserWarning, match="radians"):
        OpenCVDescriptor(name).compute(f0, radians)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        OpenCVDescriptor(name).compute(f0, k0)
        OpenCVDescriptor("brisk").compute(f0, radians)


def test_image_patch_descriptors_warn_on_angles_in_radians(pair):
    """The image-patch descriptors (BRAND, DaLI, the TFeat- and Log-Polar-style nets) read their
    keypoints through `keypoint_arrays`, which warns of radians as the OpenCV baselines do."""
    import warnings

    from geofeat.descriptors.patches import keypoint_arrays

    f0, _, k0, _ = pair
    with pytest.warns(UserWarning, match="radians"):
        keypoint_arrays(Keypoints(k0.xy, np.radians(k0.angles), k0.sizes, k0.responses), "dali", f0.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        keypoint_arrays(k0, "dali", f0.shape)
        keypoint_arrays(k0.xy, "dali", f0.shape)  # bare positions: angle 0


@pytest.mark.parametrize("name", BASELINES)
def test_nan_or_infinite_angles_are_refused_by_name(name):
    """A NaN or infinite keypoint angle crashed the process in ORB (segmentation fault), was an
    OpenCV assertion in DAISY, and gave valid all-zero SIFT descriptors."""
    frame = geofeat.read_demo_frame()
    xy = np.array([[320.0, 240.0], [300.0, 200.0]])
    for bad in (np.nan, np.inf):
        kps = Keypoints(xy, np.array([30.0, bad]), np.full(2, 10.0), np.zeros(2))
        with pytest.raises(ValueError, match="keypoints: 1 keypoint angle"):
            OpenCVDescriptor(name).compute(frame, kps)
    # without the angle, no angle is read
    assert OpenCVDescriptor(name, use_angle=False).compute(frame, kps).keypoints.shape == (2, 2)


def test_daisy_takes_angles_outside_0_to_360():
    """cv2.KeyPoint's default angle is -1, and 360 or 390 degrees are the angles 0 and 30: OpenCV's
    DAISY asserted 0 <= angle < 360; now they describe like their equivalents in [0, 360)."""
    frame = geofeat.read_demo_frame()
    d = OpenCVDescriptor("daisy")

    def describe(angles):
        return d.compute(frame, [cv2.KeyPoint(320.0, 240.0, 10.0, float(a)) for a in angles])

    got, ref = describe([-1.0, 360.0, 390.0]), describe([359.0, 0.0, 30.0])
    assert got.valid.all()
    np.testing.assert_allclose(got.descriptors, ref.descriptors, atol=1e-6)
    assert cv2.KeyPoint(1.0, 2.0, 3.0).angle == -1  # what a user gets without an angle


def test_sift_describes_each_keypoint_as_opencv_sift_does():
    """The "sift" baseline on SIFT's own keypoints is OpenCV's SIFT descriptor (detectAndCompute).
    OpenCV's `compute` reads the pyramid octave and layer from cv2.KeyPoint.octave, which Keypoints
    does not keep: with octave 0 every keypoint was described on the first pyramid image (for the
    keypoints larger than 8 px, a median relative difference of ~0.5 from SIFT's own descriptor)."""
    frame = geofeat.read_demo_frame()
    sift = cv2.SIFT_create(nfeatures=300)
    kps, expected = sift.detectAndCompute(to_uint8(frame.image), None)
    F = OpenCVDescriptor("sift").compute(frame, Keypoints.from_cv(kps))
    assert F.valid.all()
    sizes = np.array([k.size for k in kps])
    assert (sizes > 8).sum() > 20 and (sizes < 3.2).sum() > 20  # octaves -1 (upsampled image) to >= 1
    diff = np.linalg.norm(F.descriptors - expected, axis=1) / np.linalg.norm(expected, axis=1)
    assert np.median(diff) < 1e-3 and np.percentile(diff, 95) < 0.05, (np.median(diff), np.percentile(diff, 95))
    # a keypoint is described alike alone (OpenCV would build the pyramid from octave 0, not -1)
    big = int(np.argmax(sizes))
    alone = OpenCVDescriptor("sift").compute(frame, Keypoints.from_cv([kps[big]]))
    np.testing.assert_allclose(alone.descriptors[0], F.descriptors[big], atol=1e-4)


def test_sift_octave_from_size_round_trips_opencvs_packing():
    frame = geofeat.read_demo_frame()
    kps = cv2.SIFT_create(nfeatures=500).detect(to_uint8(frame.image), None)
    packed = sift_octave(np.array([k.size for k in kps]), frame.shape)
    np.testing.assert_array_equal(packed, [k.octave & 0xFFFF for k in kps])  # byte 3 holds SIFT's sub-layer offset
    # tiny and huge sizes stay within the octaves the image has
    extreme = sift_octave(np.array([0.1, 1e5]), (480, 640))
    assert (extreme & 255).tolist() == [255, 6] and (extreme >> 8).tolist() == [1, 3]


def test_daisy_is_invariant_to_image_contrast():
    """DAISY normalises each of its histograms (Tola et al.); OpenCV's default (NRM_NONE) returned raw
    gradient magnitudes, so halving the image's contrast halved the descriptor (a relative change of
    0.5), and shading on a deforming surface moved descriptors as much."""
    frame = geofeat.read_demo_frame()
    dim = geofeat.RGBDFrame(0.25 + 0.5 * frame.image, frame.depth, frame.K)
    kps = detect(frame, 200, detector="sift", require_depth=False, border_px=20)
    d = OpenCVDescriptor("daisy")
    a, b = d.compute(frame, kps), d.compute(dim, kps)
    assert a.valid.all() and b.valid.all()
    diff = np.linalg.norm(a.descriptors - b.descriptors, axis=1) / np.linalg.norm(a.descriptors, axis=1)
    assert np.median(diff) < 0.05, np.median(diff)
    # each of the 25 histograms (8 bins) has unit length
    norms = np.linalg.norm(a.descriptors.reshape(len(kps), 25, 8), axis=2)
    assert np.median(np.abs(norms - 1)) < 1e-3


@pytest.mark.parametrize("name, least_valid", [("brisk", 0.9), ("freak", 0.8)])
def test_brisk_and_freak_keep_their_border_keypoints_and_their_scale_invariance(name, least_valid):
    """BRISK and FREAK drop keypoints whose (size-scaled) pattern leaves the image; the protocol counts
    them as misses. At 6x SIFT's size they dropped 12% / 23% of the demo frame's 2048 protocol
    keypoints (FREAK's matching score on held-out simulated sequences: 0.190 at 6x, 0.211 at 4x).
    The factor must still be large enough for a 0.6x scaled copy to match (at 1x: 0.12 / 0.15)."""
    frame = geofeat.read_demo_frame()
    kps = detect(frame, 2048, detector="sift", keypoint_set="protocol")
    assert OpenCVDescriptor(name).compute(frame, kps).valid.mean() >= least_valid
    # the same keypoints on a copy scaled by 0.6 about the centre; every keypoint counts (invalid = miss)
    H, W = frame.shape
    A = cv2.getRotationMatrix2D(((W - 1) / 2, (H - 1) / 2), 0.0, 0.6)
    small = geofeat.RGBDFrame(cv2.warpAffine(frame.image, A, (W, H), flags=cv2.INTER_AREA), frame.depth, frame.K)
    k0 = detect(frame, 500, detector="sift", require_depth=False, border_px=3)
    k1 = Keypoints(k0.xy @ A[:, :2].T + A[:, 2], k0.angles, k0.sizes * 0.6, k0.responses)
    d = OpenCVDescriptor(name)
    m = match(d.compute(frame, k0), d.compute(small, k1))
    assert (m.matches0 == np.arange(len(k0))).mean() > 0.5


def test_orb_describes_at_the_pyramid_level_of_the_keypoint_size():
    """ORB describes a keypoint on the pyramid level its size says (cv2.KeyPoint.octave); at level 0
    for every keypoint (as before) it could not follow a scale change: 0.23 of the demo frame's
    keypoints matched on a 0.6x copy, 0.53 now."""
    assert orb_level(np.array([1.0, 31.0, 37.2, 31 * 1.2 ** 3, 1e4]), 31, 1.2, 8).tolist() == [0, 0, 1, 3, 7]
    frame = geofeat.read_demo_frame()
    H, W = frame.shape
    A = cv2.getRotationMatrix2D(((W - 1) / 2, (H - 1) / 2), 0.0, 0.6)
    small = geofeat.RGBDFrame(cv2.warpAffine(frame.image, A, (W, H), flags=cv2.INTER_AREA), frame.depth, frame.K)
    k0 = detect(frame, 500, detector="sift", require_depth=False, border_px=40)
    k1 = Keypoints(k0.xy @ A[:, :2].T + A[:, 2], k0.angles, k0.sizes * 0.6, k0.responses)
    d = OpenCVDescriptor("orb")
    F0, F1 = d.compute(frame, k0), d.compute(small, k1)
    assert F0.valid.mean() > 0.95 and F1.valid.mean() > 0.95
    assert (match(F0, F1).matches0 == np.arange(len(k0))).mean() > 0.45
