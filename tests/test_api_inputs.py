"""Unusual but plausible inputs to the public Python API, as a researcher passes them from a notebook
(masked depth maps, a colour array edited after the frame is made, arrays where paths are expected,
arguments in the wrong order): each either works as the user means or is a one-line error naming
the argument, never a silently wrong result or an AttributeError from deep inside."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

import geofeat
from geofeat import Features, RGBDFrame
from geofeat.io import read_depth

H, W = 120, 160
K = np.array([[150.0, 0.0, 79.5], [0.0, 150.0, 59.5], [0.0, 0.0, 1.0]])


def _colour(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 2.0)
    gray = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return np.dstack([gray, np.roll(gray, 7, axis=1), np.roll(gray, 5, axis=0)])


def _depth() -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W]
    depth = (1.0 + 0.1 * np.sin(x / 20.0) * np.cos(y / 25.0)).astype(np.float32)
    depth[40:60, 60:90] = 0.0  # a hole
    return depth


# ---------------------------------------------------------------- masked depth maps
def _masked(fill: float) -> np.ma.MaskedArray:
    """The depth with its hole masked, and `fill` stored under the mask (a sensor's no-data code)."""
    depth = _depth()
    return np.ma.masked_array(np.where(depth > 0, depth, fill), mask=depth == 0)


@pytest.mark.parametrize("fill", [0.0, 9.0, -1.0, np.nan])
def test_masked_depth_pixels_are_missing_depth(fill):
    """RGBDFrame(image, np.ma.masked_array(depth, mask=no_data), K) used the values stored under the
    mask: a no-data code of 9.0 became a surface 9 m away (silently), -1 or NaN (np.ma.masked_invalid)
    were refused as 'negative values' / 'NaN' although the user had masked them."""
    frame = RGBDFrame(_colour(), _masked(fill), K)
    np.testing.assert_array_equal(frame.depth, _depth())


def test_depth_noise_reads_masked_pixels_as_missing():
    """depth_noise(masked depth, K) measured the no-data values under the mask as a surface: no
    holes, and the step into them as slope noise."""
    expected = geofeat.depth_noise(_depth(), K)
    assert geofeat.depth_noise(_masked(9.0), K) == expected


def test_write_frame_writes_masked_depth_as_missing(tmp_path):
    """write_frame(..., masked depth) wrote the values under the mask into the depth PNG."""
    geofeat.write_frame(tmp_path, "f", _colour(), _masked(9.0))
    written = read_depth(tmp_path / "f-depth.png")
    np.testing.assert_array_equal(written == 0, _depth() == 0)


# ---------------------------------------------------------------- the frame's colour image
def test_a_frame_keeps_its_own_colour_image():
    """The frame kept the caller's colour array itself (its depth and K are copies): drawing the
    detections on that array afterwards (cv2.circle(img, ...), as notebooks do) changed
    frame.color, and frame.rotated90() / roll_camera, which start from the colour image, then
    described the drawing, not the frame."""
    img = _colour()
    frame = RGBDFrame(img, _depth(), K)
    before = frame.image.copy()
    img[:] = 255  # the caller draws on (here: blanks) its own array
    assert frame.color is not img
    assert (frame.color != 255).any()
    np.testing.assert_array_equal(frame.rotated90(4).image, before)


def test_a_frame_is_immutable_its_arrays_its_own_read_only_copies():
    """frame.image or frame.depth edited in place after the frame was made went unnoticed by what is
    cached on the frame (the depth profile "auto" picked, the mesh prefetch) and by the descriptors,
    which then described old and new data mixed. A frame's arrays are now its own read-only copies: an
    edit in place raises numpy's error, an edit of the caller's arrays does not reach the frame, and a
    frame made from it (`with_image`, `rotated90`, `roll_camera`) is read-only too."""
    from geofeat.frame import roll_camera

    colour, gray, depth, K_given = _colour(), _colour()[:, :, 0].astype(np.float32) / 255, _depth(), K.copy()
    for image in (colour, gray):
        frame = RGBDFrame(image, depth, K_given)
        for name in ("image", "depth", "K", "color"):
            array = getattr(frame, name)
            if array is None:  # a gray frame has no colour image
                continue
            assert not array.flags.writeable, name
            with pytest.raises(ValueError, match="read-only"):
                array[0, 0] += 1
        before = frame.image.copy(), frame.depth.copy()
        image[:] = 0  # the caller reuses its arrays: the frame keeps its own
        depth[:] = 2.0
        K_given[0, 0] = 300.0
        np.testing.assert_array_equal(frame.image, before[0])
        np.testing.assert_array_equal(frame.depth, before[1])
        assert frame.K[0, 0] == K[0, 0]
        depth[:], K_given[:] = _depth(), K
        for made in (frame.with_image(frame.image * 0.5), frame.rotated90(1), roll_camera(frame, 10.0)[0]):
            assert not (made.image.flags.writeable or made.depth.flags.writeable or made.K.flags.writeable)


# ---------------------------------------------------------------- arrays where paths are expected
def test_read_frame_names_an_array_given_for_a_path(tmp_path):
    """read_frame(rgb, depth, K) with the camera matrix (an array) for intrinsics_path was a bare
    "TypeError: expected str, bytes or os.PathLike object, not ndarray" from pathlib."""
    geofeat.write_frame(tmp_path, "f", _colour(), _depth())
    with pytest.raises(TypeError, match=r"^intrinsics_path: expected a file path.*RGBDFrame"):
        geofeat.read_frame(tmp_path / "f-rgb.png", tmp_path / "f-depth.png", K)
    with pytest.raises(TypeError, match=r"^rgb_path: expected a file path"):
        geofeat.read_frame(_colour(), tmp_path / "f-depth.png", tmp_path / "intrinsics.xml")


def test_features_name_cv2_keypoints():
    """Features(list of cv2.KeyPoint, ...) was "TypeError: float() argument must be a string or a
    real number, not 'cv2.KeyPoint'", naming no argument."""
    kps = [cv2.KeyPoint(10.0, 20.0, 5.0), cv2.KeyPoint(30.0, 40.0, 5.0)]
    with pytest.raises(TypeError, match=r"^keypoints: .*cv2.KeyPoint"):
        Features(kps, np.zeros((2, 4), np.float32), None)


# ---------------------------------------------------------------- arguments in the wrong order
@pytest.mark.parametrize("name", ["geobit", "geopatch", "orb", "brand"])
def test_compute_names_a_frame_that_is_not_one(name):
    """descriptor.compute(keypoints, frame) (arguments swapped) or compute(image, keypoints) was an
    AttributeError ("'Keypoints' object has no attribute 'shape'") for GeoBit, GeoPatch and the
    OpenCV baselines, and for BRAND a ValueError saying the frame had no depth map."""
    frame = RGBDFrame(_colour(), _depth(), K)
    keypoints = np.array([[40.0, 30.0], [120.0, 90.0]])
    descriptor = geofeat.make_descriptor(name)
    with pytest.raises(TypeError, match=r"^frame: expected an RGBDFrame, got ndarray"):
        descriptor.compute(keypoints, frame)
    with pytest.raises(TypeError, match=r"^frame: expected an RGBDFrame, got ndarray"):
        descriptor.compute(frame.image, keypoints)


def test_build_mesh_names_a_frame_that_is_not_one():
    """build_mesh(depth) was "AttributeError: 'numpy.ndarray' object has no attribute 'depth'"."""
    with pytest.raises(TypeError, match=r"^frame: expected an RGBDFrame, got ndarray"):
        geofeat.build_mesh(_depth())


def test_valid_inputs_in_other_forms_give_the_same_results():
    """Plain checks of what already worked: the same frame from uint8, uint16 and float colour, and
    the same keypoints as float64, float32, int, a list of tuples and cv2.KeyPoints, read-only or
    Fortran-ordered, give the same descriptors."""
    colour = _colour()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frames = [RGBDFrame(colour, _depth(), K), RGBDFrame(colour.astype(np.uint16) * 257, _depth(), K),
                  RGBDFrame(colour / 255.0, _depth(), K)]
    assert max(float(np.abs(f.image - frames[0].image).max()) for f in frames) < 1.0 / 255
    xy = np.array([[40.0, 30.0], [120.0, 90.0], [100.0, 20.0]])
    read_only = xy.copy()
    read_only.setflags(write=False)
    describer = geofeat.GeoBit()
    ref = describer.compute(frames[0], xy)
    for keypoints in (xy.astype(np.float32), xy.astype(int), [tuple(p) for p in xy], read_only,
                      np.asfortranarray(xy), [cv2.KeyPoint(float(x), float(y), 8.0) for x, y in xy]):
        got = describer.compute(frames[0], keypoints)
        np.testing.assert_array_equal(got.descriptors, ref.descriptors)
        np.testing.assert_array_equal(got.valid, ref.valid)


def test_a_one_channel_image_gives_no_one_channel_colour_image():
    """RGBDFrame(gray[:, :, None], ...) kept the (H, W, 1) array as `frame.color`, documented as
    (H, W, 3) BGR: the pictures of `geofeat.viz` drawn on it came back (H, W, 1), their coloured
    rings and match lines grey."""
    from geofeat.viz import to_bgr

    gray = cv2.cvtColor(_colour(), cv2.COLOR_BGR2GRAY)
    frame = RGBDFrame(gray[:, :, None], _depth(), K)
    np.testing.assert_array_equal(frame.image, RGBDFrame(gray, _depth(), K).image)
    assert frame.color is None or frame.color.shape == (H, W, 3)
    assert to_bgr(frame).shape == (H, W, 3)


# ---------------------------------------------------------------- review-newuser: images from PIL and torch
def test_a_pil_image_is_read_as_rgb():
    """RGBDFrame(PIL.Image.open(path), ...) was np.asarray'ed and read as BGR: red and blue swapped in
    the gray image the detectors and descriptors see, and in the colour copy drawn by geofeat.viz,
    without a word. A PIL image knows it holds RGB."""
    Image = pytest.importorskip("PIL.Image")
    colour = _colour()  # BGR
    ref = RGBDFrame(colour, _depth(), K)
    rgb = Image.fromarray(np.ascontiguousarray(colour[:, :, ::-1]), "RGB")
    for image in (rgb, rgb.convert("RGBA")):
        frame = RGBDFrame(image, _depth(), K)
        np.testing.assert_array_equal(frame.color, ref.color)
        np.testing.assert_array_equal(frame.image, ref.image)
    gray = Image.fromarray(cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), "L")
    np.testing.assert_array_equal(RGBDFrame(gray, _depth(), K).image, RGBDFrame(np.asarray(gray), _depth(), K).image)


@pytest.mark.parametrize("image, hint", [
    (lambda c: np.ascontiguousarray(c.transpose(2, 0, 1)), r"channels first\? transpose it to \(H, W, C\)"),
    (lambda c: np.dstack([c, c[:, :, :1]]), r"drop the alpha channel"),
])
def test_an_image_of_another_layout_says_how_to_fix_it(image, hint):
    """A (3, H, W) torch-style array or an (H, W, 4) RGBA one: "expected shape (H, W) or (H, W, 3),
    got (3, 120, 160)" said what was wrong but not the likely cause and its fix."""
    with pytest.raises(ValueError, match=rf"image: expected shape \(H, W\) or \(H, W, 3\), got .*; {hint}"):
        RGBDFrame(image(_colour()), _depth(), K)


@pytest.mark.parametrize("stretch", [float("nan"), -8.0, 0.0, float("inf")])
def test_build_mesh_refuses_a_max_edge_stretch_that_is_not_a_positive_number(stretch):
    """NaN kept every face across depth steps (rays then walked onto the background), a negative value
    acted as its absolute value, and 0 cut every face, all without a word."""
    frame = geofeat.read_demo_frame()
    with pytest.raises(ValueError, match="max_edge_stretch"):
        geofeat.build_mesh(frame, "kinect", max_edge_stretch=stretch)


def test_a_big_endian_uint16_image_reads_as_the_native_one():
    """A big-endian uint16 image (raw 16-bit PNG bytes, FITS) is not `== np.uint16`: it was read as
    floats, refused as "image: >u2 images must lie in [0, 1]", and one holding only 0 and 1 was taken
    as black and white instead of nearly black, without a word."""
    colour = _colour().astype(np.uint16) * 257
    native = RGBDFrame(colour, _depth(), K)
    np.testing.assert_array_equal(RGBDFrame(colour.astype(">u2"), _depth(), K).image, native.image)
    gray = colour[:, :, 0]
    np.testing.assert_array_equal(RGBDFrame(gray.astype(">u2"), _depth(), K).image, RGBDFrame(gray, _depth(), K).image)
    np.testing.assert_array_equal(native.with_image(gray.astype(">u2")).image, native.with_image(gray).image)
    flags = (gray > 128 * 257).astype(np.uint16)  # 0 and 1 of 65535: nearly black, with a warning
    with pytest.warns(UserWarning, match="nearly black"):
        expected = RGBDFrame(flags, _depth(), K).image
    with pytest.warns(UserWarning, match="nearly black"):
        np.testing.assert_array_equal(RGBDFrame(flags.astype(">u2"), _depth(), K).image, expected)
