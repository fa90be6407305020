"""Readers of the public dataset layout, on the shipped real Kinect frame."""

import shutil

import cv2
import numpy as np
import pytest

import geofeat
from geofeat.io import demo_data_dir, read_depth, read_intrinsics, read_landmarks, write_intrinsics, write_landmarks


def test_read_demo_frame():
    frame = geofeat.read_demo_frame()
    assert frame.shape == (480, 640)
    assert frame.image.dtype == np.float32 and 0 <= frame.image.min() and frame.image.max() <= 1
    assert frame.color is not None and frame.color.shape == (480, 640, 3)
    np.testing.assert_allclose(frame.K[0, 0], 525.0, atol=1e-3)
    valid = frame.depth[frame.depth > 0]
    assert 0.6 < valid.min() and valid.max() < 1.2  # metres


def test_landmarks():
    ids, xy, visible = read_landmarks(demo_data_dir() / "cloud_1.csv")
    assert ids.tolist() == list(range(51))
    assert xy.shape == (51, 2) and visible.all()
    np.testing.assert_array_equal(xy[0], [245, 202])


def test_read_sequence_reference_first_and_round_trips(tmp_path):
    src = demo_data_dir()
    for name in ("frame_b", "frame_a", "cloud_master"):
        shutil.copy(src / "cloud_1-rgb.png", tmp_path / f"{name}-rgb.png")
        shutil.copy(src / "cloud_1-depth.png", tmp_path / f"{name}-depth.png")
    write_intrinsics(tmp_path / "intrinsics.xml", np.array([[500.0, 0, 320], [0, 501.0, 240], [0, 0, 1]]))
    write_landmarks(tmp_path / "cloud_master.csv", [0, 1], np.array([[1.5, 2.25], [-1, 3]]), [1, 1])
    seq = geofeat.read_sequence(tmp_path)
    assert seq.names == ["cloud_master", "frame_a", "frame_b"]
    assert seq.reference == "cloud_master"
    np.testing.assert_allclose(seq.K[1, 1], 501.0)
    ids, xy, visible = seq.landmarks("cloud_master")
    np.testing.assert_allclose(xy[0], [1.5, 2.25])
    assert visible.tolist() == [True, False]  # negative coordinate -> not visible
    frame = seq.frame(1)
    assert frame.shape == (480, 640)


def test_depth_scale_from_geofeat_json(tmp_path):
    src = demo_data_dir()
    shutil.copy(src / "cloud_1-rgb.png", tmp_path / "ref-rgb.png")
    raw = cv2.imread(str(src / "cloud_1-depth.png"), cv2.IMREAD_ANYDEPTH)
    cv2.imwrite(str(tmp_path / "ref-depth.png"), (raw // 2).astype(np.uint16))  # 2 mm units
    shutil.copy(src / "intrinsics.xml", tmp_path)
    (tmp_path / "geofeat.json").write_text('{"depth_scale": 0.002}')
    frame = geofeat.read_sequence(tmp_path).frame(0)
    reference = geofeat.read_demo_frame()
    both = (frame.depth > 0) & (reference.depth > 0)
    np.testing.assert_allclose(frame.depth[both], reference.depth[both], atol=0.0021)
    (tmp_path / "geofeat.json").write_text('{"depth_scale": 1e308}')  # made every depth inf
    with pytest.raises(ValueError, match="depth_scale: 1e.308 m per depth unit is implausible"):
        geofeat.read_sequence(tmp_path)


def test_missing_and_unreadable_files(tmp_path):
    src = demo_data_dir()
    with pytest.raises(ValueError, match="rgb_path.*not found"):
        geofeat.read_frame(tmp_path / "nope-rgb.png", src / "cloud_1-depth.png", src / "intrinsics.xml")
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="depth_path.*decode"):
        read_depth(tmp_path / "bad.png")
    (tmp_path / "intrinsics.xml").write_text("<?xml version='1.0'?><opencv_storage><other>1</other></opencv_storage>")
    with pytest.raises(ValueError, match="intrinsics"):
        read_intrinsics(tmp_path / "intrinsics.xml")
    with pytest.raises(ValueError, match="folder"):
        geofeat.read_sequence(tmp_path)
    with pytest.raises(ValueError, match="millimetres"):
        geofeat.read_frame(src / "cloud_1-rgb.png", src / "cloud_1-depth.png", src / "intrinsics.xml", depth_scale=1.0)


def test_sequence_without_intrinsics(tmp_path):
    src = demo_data_dir()
    shutil.copy(src / "cloud_1-rgb.png", tmp_path / "ref-rgb.png")
    shutil.copy(src / "cloud_1-depth.png", tmp_path / "ref-depth.png")
    with pytest.raises(ValueError, match="intrinsics"):
        geofeat.read_sequence(tmp_path)


def test_sequence_frames_are_named_or_indexed_within_the_sequence():
    """An index past the end was an IndexError, a numpy index a file "1-rgb.png" not found, and a
    path-like name read a frame outside the sequence."""
    seq = geofeat.read_sequence(demo_data_dir())
    assert seq.frame(np.int64(0)).image.shape[:2] == seq.frame("cloud_1").image.shape[:2]
    for key, message in ((1, "index 1 out of range"), ("nope", "'nope' is not in the sequence"),
                         ("../kinect_example/cloud_1", "is not in the sequence"), (True, "is not in the sequence")):
        with pytest.raises(ValueError, match=message):
            seq.frame(key)
        with pytest.raises(ValueError, match=message):
            seq.landmarks(key)
