"""SIFT keypoint detection on RGB-D frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import geofeat
from geofeat.keypoints import Keypoints, detect


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
    with_holes = detect(frame, n=0, require_depth=False)
    xi, yi = np.rint(with_holes.xy).astype(int).T
    assert (frame.depth[yi, xi] == 0).any()  # the demo frame has missing depth with texture
    assert len(detect(frame, n=0)) < len(with_holes)


def test_to_cv_round_trip_and_compute(frame):
    kp = detect(frame, n=50)
    cvk = kp.to_cv()
    assert all(isinstance(k, cv2.KeyPoint) for k in cvk)
    back = Keypoints.from_cv(cvk)
    assert np.allclose(back.xy, kp.xy, atol=1e-4) and np.allclose(back.angles, kp.angles, atol=1e-3)
    # GeoBit keeps angles and sizes of Keypoints
    from geofeat.descriptors import GeoBit

    f = GeoBit().compute(frame, kp)
    assert f.descriptors.shape == (50, 16, 64) and np.allclose(f.angles, kp.angles)


def test_bad_arguments(frame):
    with pytest.raises(ValueError, match="n"):
        detect(frame, n=-1)
    with pytest.raises(TypeError, match="frame"):
        detect(np.zeros((10, 10)))
    with pytest.raises(ValueError, match="mask"):
        detect(frame, mask=np.ones((3, 3), np.uint8))
