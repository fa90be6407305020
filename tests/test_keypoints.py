"""SIFT keypoint detection on RGB-D frames (`geofeat.detect(..., detector="sift")`), and the default
detector."""

from __future__ import annotations

from functools import partial

import cv2
import numpy as np
import pytest

import geofeat
from geofeat.keypoints import DEFAULT_DETECTOR, Keypoints
from geofeat.keypoints import detect as detect_any

detect = partial(detect_any, detector="sift")


@pytest.fixture(scope="module")
def frame():
    return geofeat.read_demo_frame()


def test_detect_strongest_first_with_depth(frame):
    kp = detect(frame, n=500)
    assert isinstance(kp, Keypoints) and len(kp) == 500
    assert kp.xy.shape == (500, 2) and kp.angles.shape == kp.sizes.shape == kp.responses.shape == (500,)
    assert (np.diff(kp.responses) <= 0).all()
    xi, yi = np.rint(kp.xy).astype(int).T
    assert (frame.depth[yi, xi] > 0).all()
    H, W = frame.shape
    assert (kp.xy >= 3).all() and (kp.xy[:, 0] <= W - 4).all() and (kp.xy[:, 1] <= H - 4).all()
    assert ((kp.angles >= 0) & (kp.angles < 360)).all() and (kp.sizes > 0).all()
    # the first 100 of a larger detection are the same keypoints
    assert np.allclose(detect(frame, n=100).xy, kp.xy[:100])


def test_depth_filter_removes_keypoints_on_holes(frame):
    with_holes = detect(frame, n=None, require_depth=False)
    xi, yi = np.rint(with_holes.xy).astype(int).T
    assert (frame.depth[yi, xi] == 0).any()  # the demo frame has missing depth with texture
    assert len(detect(frame, n=None)) < len(with_holes)


def test_to_cv_round_trip_and_compute(frame):
    kp = detect(frame, n=50)
    cvk = kp.to_cv()
    assert len(cvk) == 50
    back = Keypoints.from_cv(cvk)
    assert np.allclose(back.xy, kp.xy, atol=1e-4) and np.allclose(back.angles, kp.angles, atol=1e-3)
    # GeoBit keeps angles and sizes of Keypoints
    from geofeat.descriptors import GeoBit

    f = GeoBit().compute(frame, kp)
    assert f.descriptors.shape == (50, 16, 64) and np.allclose(f.angles, kp.angles)


def test_the_default_detector_is_geokey_and_sift_options_need_sift(frame):
    assert DEFAULT_DETECTOR == "geokey"
    default = detect_any(frame, 300)
    np.testing.assert_array_equal(default.xy, detect_any(frame, 300, detector="geokey").xy)
    assert np.all(default.angles == 0)  # GeoKey gives no orientation; SIFT's keypoints have one
    with pytest.raises(TypeError, match="sift"):
        detect_any(frame, 300, contrast_threshold=0.01)


def test_bad_arguments(frame):
    with pytest.raises(ValueError, match="n"):
        detect(frame, n=-1)
    with pytest.raises(TypeError, match="frame"):
        detect(np.zeros((10, 10)))
    with pytest.raises(ValueError, match="mask"):
        detect(frame, mask=np.ones((3, 3), np.uint8))


def test_protocol_set_keeps_opencv_duplicates_and_unique_drops_them(frame):
    proto = detect(frame, n=2048, keypoint_set="protocol")
    assert len(proto) == 2048 and (np.diff(proto.responses) <= 0).all()
    positions = np.unique(np.round(proto.xy, 2), axis=0)
    assert len(positions) < len(proto)  # SIFT returns a position once per dominant orientation
    unique = detect(frame, n=2048)
    assert len(np.unique(np.round(unique.xy, 2), axis=0)) == len(unique)
    # the protocol set is what OpenCV returns for nfeatures=2048, in decreasing response
    raw = cv2.SIFT_create(nfeatures=2048, contrastThreshold=0.004).detect(
        np.clip(np.rint(frame.image * 255), 0, 255).astype(np.uint8), None)
    assert sorted(k.response for k in raw) == sorted(proto.responses.tolist())
    with pytest.raises(ValueError, match="keypoint_set"):
        detect(frame, keypoint_set="all")


@pytest.mark.parametrize("form", ["array", "list", "cv2", "Keypoints"])
def test_every_stage_takes_every_keypoint_form(frame, form):
    """One normaliser: polar patches, GeoBit, the OpenCV baselines and the heat path give the same
    result for an (N, 2) array, a list of pairs, cv2.KeyPoints and a Keypoints object."""
    from geofeat.descriptors import make_descriptor
    from geofeat.keypoints import as_keypoints

    kps = detect(frame, n=40)
    given = {"array": kps.xy, "list": kps.xy.tolist(), "cv2": kps.to_cv(), "Keypoints": kps}[form]
    assert np.allclose(as_keypoints(given).xy, kps.xy, atol=1e-4)
    reference = geofeat.polar_patches(frame, kps.xy)
    patches = geofeat.polar_patches(frame, given)
    assert len(patches) == 40 and np.allclose(patches.values, reference.values, atol=1e-4)
    f = make_descriptor("geobit").compute(frame, given)
    assert len(f) == 40 and f.valid.sum() == reference.valid.sum()
    orb = make_descriptor("orb").compute(frame, given)
    assert len(orb) == 40 and orb.valid.any()
    K = frame.K.copy()
    K[0, 2] -= 280  # the crop's camera: the principal point moves with the crop's corner
    K[1, 2] -= 200
    small = geofeat.RGBDFrame(frame.image[200:280, 280:380], frame.depth[200:280, 280:380], K)
    xy = np.array([[40.2, 30.7], [55.1, 41.3]])
    forms = {"array": xy, "list": xy.tolist(), "cv2": [cv2.KeyPoint(x, y, 8.0) for x, y in xy],
             "Keypoints": geofeat.Keypoints(xy, np.zeros(2), np.full(2, 8.0), np.zeros(2))}
    heat = geofeat.heat_polar_patches(small, forms[form], radius=0.02)
    assert len(heat) == 2 and np.allclose(heat.keypoints, xy)


def test_keypoint_errors_name_the_argument(frame):
    from geofeat.keypoints import as_keypoints

    with pytest.raises(ValueError, match="keypoints: the keypoint set is empty"):
        geofeat.GeoBit().compute(frame, np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"keypoints: expected shape \(N, 2\)"):
        geofeat.polar_patches(frame, np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"keypoints: expected shape \(N, 2\)"):
        as_keypoints([1.0, 2.0, 3.0])
    with pytest.raises(TypeError, match="keypoints"):
        as_keypoints("12,3")
    with pytest.raises(ValueError, match="off the 640x480 image"):
        geofeat.make_descriptor("sift").compute(frame, [[700.0, 10.0]])


def test_geopatch_is_a_lazy_top_level_name():
    import subprocess
    import sys

    code = ("import sys, geofeat; assert 'torch' not in sys.modules; G = geofeat.GeoPatch; "
            "assert 'torch' not in sys.modules  # the ONNX backend needs none (tests/test_geopatch_onnx.py)")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_extract_and_match_pick_geokey_for_geodesic_descriptors_and_sift_for_the_baselines():
    from geofeat.keypoints import detector_for

    assert detector_for("geopatch", None) == detector_for("geobit", None) == "geokey"
    assert detector_for("geopatch=my.pt", None) == "geokey"
    assert detector_for("orb", None) == detector_for("sift", None) == "sift"  # they take SIFT's orientation
    assert detector_for("orb", "geokey") == "geokey" and detector_for("geopatch", "sift") == "sift"  # named wins
    # geofeat.extract follows the same rule: ORB on SIFT's keypoints (it needs their orientation)
    frame = geofeat.read_demo_frame()
    orb = geofeat.extract(frame, 64, descriptor="orb")
    np.testing.assert_array_equal(orb.keypoints, geofeat.detect(frame, 64, detector="sift").xy)



def test_the_detector_follows_the_descriptor_name_in_any_case():
    """make_descriptor reads " GeoBit " as geobit; detector_for read it as a baseline and gave SIFT's
    keypoints to geofeat.extract(descriptor="GeoBit"), without a word."""
    import sys
    from pathlib import Path

    from geofeat.keypoints import detector_for

    assert detector_for(" GeoBit ") == detector_for("GeoPatch") == detector_for("GEOPATCH=my.pt") == "geokey"
    assert detector_for("ORB") == "sift"
    sys.path.insert(0, str(Path(__file__).parent))
    from surfaces import plane_frame

    frame = plane_frame((120, 160))
    np.testing.assert_array_equal(geofeat.extract(frame, 20, descriptor="GeoBit").keypoints,
                                  geofeat.detect(frame, 20).xy)

def test_keypoints_fields_must_have_one_entry_per_keypoint():
    with pytest.raises(ValueError, match=r"angles: expected shape \(3,\) like xy"):
        Keypoints(np.zeros((3, 2)), np.zeros(2), np.zeros(3), np.zeros(3))  # to_cv dropped the third keypoint
    with pytest.raises(ValueError, match="xy: expected shape"):
        Keypoints(np.zeros((3, 3)), np.zeros(3), np.zeros(3), np.zeros(3))
    kps = Keypoints([[1, 2], [3, 4]], [0, 90], [8, 8], [1, 0.5])  # lists: float64 arrays (was an AttributeError)
    assert kps.xy.dtype == np.float64 and len(kps.to_cv()) == 2
    kps.angles = np.zeros(5)  # replaced after construction
    with pytest.raises(ValueError, match="keypoints: angles must have one entry per keypoint"):
        geofeat.as_keypoints(kps)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "0.01", None])
def test_contrast_threshold_must_be_a_finite_number(frame, value):
    """NaN used to pass the `< 0` check and run SIFT with it; a string or None was a TypeError of `<`."""
    with pytest.raises(ValueError, match="contrast_threshold"):
        detect(frame, 10, contrast_threshold=value)


@pytest.mark.parametrize("value", [float("nan"), None, -1])
def test_border_must_be_a_whole_number_of_pixels(frame, value):
    """NaN silently dropped every keypoint; None was a TypeError of `>=`."""
    with pytest.raises(ValueError, match="border_px"):
        detect(frame, 10, border_px=value)


def test_an_integer_index_gives_one_keypoint(frame):
    """kps[0] used to fail with "xy: expected shape (N, 2) ..., got (2,)"."""
    kps = detect(frame, 10)
    for i in (0, -1, np.int64(3)):
        one = kps[i]
        assert len(one) == 1
        np.testing.assert_array_equal(one.xy, kps.xy[[i]])
        assert one.responses[0] == kps.responses[i]


def test_indexing_takes_masks_slices_and_index_arrays_and_refuses_the_rest(frame):
    """kps[True] gave a shape error from the constructor (numpy adds an axis for a bool index)."""
    kps = detect(frame, 10)
    mask = kps.responses > np.median(kps.responses)
    np.testing.assert_array_equal(kps[mask].xy, kps.xy[mask])
    np.testing.assert_array_equal(kps[2:5].xy, kps.xy[2:5])
    np.testing.assert_array_equal(kps[[4, 1]].xy, kps.xy[[4, 1]])
    assert len(kps[[]]) == 0 and len(kps[np.zeros(0, int)]) == 0
    for bad in (True, np.bool_(False), (0, 1), np.zeros((2, 2), int), [0.5, 1.5]):
        with pytest.raises(TypeError, match="Keypoints: index"):
            kps[bad]
    with pytest.raises(IndexError):
        kps[np.ones(3, bool)]  # a mask of the wrong length


def test_detector_names_in_any_case_are_recorded_lower_case(frame):
    """`--detector SIFT` and detect(frame, detector="GeoKey") were refused; a weights path keeps its case."""
    from geofeat.detectors.geokey import SHIPPED_WEIGHTS
    from geofeat.keypoints import check_detector_name

    assert check_detector_name("SIFT") == "sift" and check_detector_name(" GeoKey") == "geokey"
    assert check_detector_name(f"GeoKey={SHIPPED_WEIGHTS}") == f"geokey={SHIPPED_WEIGHTS}"
    np.testing.assert_array_equal(detect_any(frame, 100, detector="Sift").xy, detect_any(frame, 100, detector="sift").xy)
    np.testing.assert_array_equal(detect_any(frame, 100, detector="GEOKEY").xy, detect_any(frame, 100, detector="geokey").xy)
    with pytest.raises(ValueError, match="expected one of sift, geokey or geokey=WEIGHTS, got 'surf'"):
        check_detector_name("surf")
    with pytest.raises(ValueError, match="got 'SIFT=w.npz'"):
        check_detector_name("SIFT=w.npz")


@pytest.mark.parametrize("detector", ["sift", "geokey"])
def test_a_mask_with_nan_or_of_another_kind_is_refused(detector):
    """NaN is nonzero, so a float mask with NaN for "unknown" allowed those pixels without a word."""
    frame = geofeat.read_demo_frame()
    mask = np.zeros(frame.shape, np.float32)
    mask[100:300, 100:400] = 1.0
    kept = geofeat.detect(frame, 200, detector=detector, mask=mask)
    assert len(kept) and (kept.xy[:, 0] >= 99).all() and (kept.xy[:, 0] <= 400).all()
    mask[0:50, 0:50] = np.nan
    with pytest.raises(ValueError, match="mask: contains NaN"):
        geofeat.detect(frame, 200, detector=detector, mask=mask)
    with pytest.raises(ValueError, match="mask: expected a bool or numeric array"):
        geofeat.detect(frame, 200, detector=detector, mask=np.full(frame.shape, "x"))
    with pytest.raises(ValueError, match="mask: expected shape"):
        geofeat.detect(frame, 200, detector=detector, mask=np.ones((10, 10)))
