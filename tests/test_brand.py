"""BRAND: the geometric test sees the surface's normals, not only the image."""

import numpy as np
import pytest

import geofeat
from geofeat.descriptors.brand import BRAND
from geofeat.matching import match

K = np.array([[300.0, 0.0, 100.0], [0.0, 300.0, 100.0], [0.0, 0.0, 1.0]])


def _frames(shape=(200, 200)):
    """One image over a flat plane at 1 m and over a ridge whose crest (at x = 100 px, 1 m) comes
    towards the camera: same image, same depth at the crest, different normals around it."""
    rng = np.random.default_rng(0)
    image = np.clip(rng.uniform(0, 1, shape).astype(np.float32), 0, 1)
    H, W = shape
    X = (np.arange(W) - K[0, 2]) / K[0, 0]  # x / z of each column
    flat = np.ones(shape, np.float32)
    # ridge: z = 1 + 1.5 |x| (slopes of 56 degrees); on the ray x = X z: z = 1 / (1 - 1.5 |X|)
    ridge = np.broadcast_to((1.0 / (1.0 - 1.5 * np.abs(X))).astype(np.float32), shape).copy()
    return geofeat.RGBDFrame(image, flat, K), geofeat.RGBDFrame(image, ridge, K)


def test_bits_change_under_a_bend_that_keeps_the_image():
    flat, ridge = _frames()
    xy = np.stack([np.full(20, 100.0), np.linspace(60, 140, 20)], axis=1)  # on the crest
    d = BRAND()
    f0, f1, f0b = d.compute(flat, xy), d.compute(ridge, xy), d.compute(flat, xy)
    assert f0.descriptors.shape == (20, 32) and f0.descriptors.dtype == np.uint8
    assert f0.valid.all() and f1.valid.all()
    bits = lambda a, b: np.unpackbits(a ^ b, axis=1).sum(axis=1)  # noqa: E731
    assert (bits(f0.descriptors, f0b.descriptors) == 0).all()  # deterministic
    changed = bits(f0.descriptors, f1.descriptors)
    # only the geometric test can differ (image and crest depth are equal); it sets bits (OR)
    assert changed.min() >= 10, changed
    assert (f1.descriptors & f0.descriptors == f0.descriptors).all()
    # and the intensity bits alone still match every keypoint to itself on the flat plane
    assert (match(f0, f0b).matches0 == np.arange(20)).all()


def test_hamming_matching_through_the_descriptor_interface():
    flat, _ = _frames()
    kps = geofeat.detect(flat, 100, detector="sift", require_depth=False, border_px=30)
    f = geofeat.make_descriptor("brand").compute(flat, kps)
    m = match(f, f)
    assert (m.matches0[f.valid] == np.flatnonzero(f.valid)).mean() > 0.95


def test_bad_input():
    flat, _ = _frames()

    class NoDepth:
        image, K, depth = flat.image, flat.K, None

    with pytest.raises(ValueError, match="depth"):
        BRAND().compute(NoDepth(), np.zeros((3, 2)))
    depth = flat.depth.copy()
    depth[:, :50] = 0  # keypoints on missing depth are invalid, the others are not
    holey = geofeat.RGBDFrame(flat.image, depth, K)
    f = BRAND().compute(holey, np.array([[20.0, 100.0], [120.0, 100.0]]))
    assert f.valid.tolist() == [False, True]
    assert not f.descriptors[0].any()


def test_off_image_keypoints_are_refused():
    """A keypoint off the image took the depth and normal of the nearest border pixel (as every other
    descriptor does, it is now refused by name)."""
    flat, _ = _frames()
    with pytest.raises(ValueError, match="keypoints: 1 keypoint.s. off the 200x200 image"):
        BRAND().compute(flat, np.array([[100.0, 100.0], [150.0, 260.0]]))


@pytest.mark.parametrize("fy", [300.0, 200.0], ids=["square pixels", "non-square pixels"])
def test_a_quarter_roll_keeps_the_bits_with_non_square_pixels(fy):
    """The patch covers the same metric extent along both image axes (fx E / z across, fy E / z down):
    with fx alone for both, a camera rolled by a quarter turn (fx and fy swap) saw another patch, and
    54-89 of the 256 bits changed at fx = 300, fy = 200."""
    from geofeat.frame import rotate_points90

    image = _frames((201, 201))[0].image
    Kn = np.array([[300.0, 0.0, 100.0], [0.0, fy, 100.0], [0.0, 0.0, 1.0]])
    frame = geofeat.RGBDFrame(image, np.ones((201, 201), np.float32), Kn)
    xy = np.array([[100.0, 100.0], [90.0, 110.0], [110.0, 95.0]])
    kps = geofeat.Keypoints(xy, np.array([30.0, 0.0, 75.0]), np.full(3, 8.0), np.zeros(3))
    rolled = frame.rotated90(1)  # an OpenCV angle a becomes a - 90 degrees
    kr = geofeat.Keypoints(rotate_points90(xy, frame.shape, 1), kps.angles - 90.0, kps.sizes, kps.responses)
    a, b = BRAND().compute(frame, kps), BRAND().compute(rolled, kr)
    assert a.valid.all() and b.valid.all()
    assert (np.unpackbits(a.descriptors ^ b.descriptors, axis=1).sum(axis=1) == 0).all()
