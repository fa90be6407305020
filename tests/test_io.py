"""Readers of the public dataset layout, on the shipped real Kinect frame."""

import json
import re
import shutil
import warnings

import cv2
import numpy as np
import pytest

import geofeat
from geofeat.io import (demo_data_dir, read_depth, read_intrinsics, read_landmarks, write_frame, write_intrinsics,
                        write_landmarks)


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


def test_landmarks_normalised_by_the_image_size_are_refused(tmp_path):
    """x, y in 0..1 (an annotation tool's normalised export) were read as pixels: every landmark in the
    top-left pixel, and `geofeat groundtruth` reported such a frame "ok" with a spline of that pixel."""
    src = demo_data_dir()
    for name in ("cloud_master", "cloud_1"):
        shutil.copy(src / "cloud_1-rgb.png", tmp_path / f"{name}-rgb.png")
        shutil.copy(src / "cloud_1-depth.png", tmp_path / f"{name}-depth.png")
        shutil.copy(src / "cloud_1.csv", tmp_path / f"{name}.csv")
    shutil.copy(src / "intrinsics.xml", tmp_path)
    seq = geofeat.read_sequence(tmp_path)
    ids, xy, visible = seq.landmarks("cloud_1")  # pixels: read
    assert visible.sum() == 51 and xy.max() > 100
    write_landmarks(tmp_path / "cloud_1.csv", ids, xy / [640, 480], visible)
    with pytest.raises(ValueError, match=r"cloud_1.csv has all 51 visible landmarks within one pixel .*multiply x by 640"):
        seq.landmarks("cloud_1")
    write_landmarks(tmp_path / "cloud_1.csv", ids, np.where(visible[:, None], xy / [640, 480], -1), visible & (ids == 0))
    assert seq.landmarks("cloud_1")[2].sum() == 1  # one landmark is no evidence of normalised coordinates


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


def test_depth_in_centimetres_is_not_called_millimetres():
    """80 cm as depth was refused as "looks like millimetres; divide by 1000", which gives 8 cm. Now
    the message gives each plausible reading with its depth_scale."""
    image = np.zeros((48, 64, 3), np.uint8)
    K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])
    with pytest.raises(ValueError, match=r"as millimetres 0.08 m \(depth_scale=0.001\), or as centimetres 0.80 m "
                                         r"\(depth_scale=0.01\)"):
        geofeat.RGBDFrame(image, np.full((48, 64), 80.0), K)
    with pytest.raises(ValueError, match=r"as millimetres 9.00 m .*tenths of a millimetre 0.90 m"):
        geofeat.RGBDFrame(image, np.full((48, 64), 9000.0), K)


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


# ---------------------------------------------------------------- audit of the layout readers and writers
K_SMALL = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])


def _small_sequence(folder, sizes=None):
    """Reference frame-000-master and target frame-001, 160x120 unless `sizes` says otherwise, depth 1 m."""
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder / "intrinsics.xml", K_SMALL)
    rng = np.random.default_rng(0)
    for name in ("frame-000-master", "frame-001"):
        h, w = (sizes or {}).get(name, (120, 160))
        write_frame(folder, name, rng.integers(0, 255, (h, w, 3), dtype=np.uint8), np.ones((h, w)))
    return folder


def test_a_three_channel_16bit_depth_png_is_refused(tmp_path):
    """IMREAD_ANYDEPTH turned it into its luminance: 969 mm was read as 0.491 m without a word."""
    raw = cv2.imread(str(demo_data_dir() / "cloud_1-depth.png"), cv2.IMREAD_ANYDEPTH)
    cv2.imwrite(str(tmp_path / "d-depth.png"), np.dstack([raw, raw // 2, raw // 3]))
    with pytest.raises(ValueError, match="d-depth.png has 3 channels; depth must be a single-channel"):
        read_depth(tmp_path / "d-depth.png")


def test_read_frame_checks_what_read_sequence_checks(tmp_path):
    """read_frame took depth stored in metres (median 1 unit = 1 mm) and a principal point off the image
    without a word, and its size and all-zero errors named no file."""
    src = demo_data_dir()
    rgb, depth, xml = src / "cloud_1-rgb.png", src / "cloud_1-depth.png", src / "intrinsics.xml"
    raw = cv2.imread(str(depth), cv2.IMREAD_ANYDEPTH)
    cv2.imwrite(str(tmp_path / "metres-depth.png"), ((raw + 500) // 1000).astype(np.uint16))
    with pytest.raises(ValueError, match="metres-depth.png: median depth 0.001 m"):
        geofeat.read_frame(rgb, tmp_path / "metres-depth.png", xml)
    write_intrinsics(tmp_path / "off.xml", np.array([[525.0, 0, 900], [0, 525, 240], [0, 0, 1]]))
    with pytest.raises(ValueError, match="off.xml: principal point"):
        geofeat.read_frame(rgb, depth, tmp_path / "off.xml")
    cv2.imwrite(str(tmp_path / "half-depth.png"), raw[::2, ::2])
    with pytest.raises(ValueError, match="half-depth.png is 320x240, the colour image .*cloud_1-rgb.png 640x480"):
        geofeat.read_frame(rgb, tmp_path / "half-depth.png", xml)
    cv2.imwrite(str(tmp_path / "zero-depth.png"), np.zeros_like(raw))
    with pytest.raises(ValueError, match="zero-depth.png: depth: every pixel is 0"):
        geofeat.read_frame(rgb, tmp_path / "zero-depth.png", xml)


def test_a_target_of_another_size_than_the_reference_is_refused(tmp_path):
    """The target was read with the reference's intrinsics (cx = 79.5 on an 80x60 image) without a word."""
    seq = geofeat.read_sequence(_small_sequence(tmp_path, {"frame-001": (60, 80)}))
    assert seq.frame(0).shape == (120, 160)
    with pytest.raises(ValueError, match="frame frame-001: colour 80x60 differs in size from the reference "
                                         r"frame-000-master \(160x120\)"):
        seq.frame("frame-001")


def test_a_frame_without_depth_is_named_by_the_sequence(tmp_path):
    """An all-zero depth PNG in a sequence said only 'depth: every pixel is 0': `geofeat extract` or
    `bench` on a sequence whose reference has no depth named neither the frame nor the folder."""
    folder = _small_sequence(tmp_path / "seq")
    cv2.imwrite(str(folder / "frame-001-depth.png"), np.zeros((120, 160), np.uint16))
    seq = geofeat.read_sequence(folder)
    assert seq.frame(0).shape == (120, 160)
    with pytest.raises(ValueError, match=r"frame frame-001 of .*seq: depth: every pixel is 0"):
        seq.frame("frame-001")


def test_write_intrinsics_refuses_what_read_intrinsics_cannot_read(tmp_path):
    """A missing folder raised a bare cv2.error (after an OpenCV log line); a 4x4 matrix was written."""
    with pytest.raises(ValueError, match="cannot write .*nope/intrinsics.xml: folder not found"):
        write_intrinsics(tmp_path / "nope" / "intrinsics.xml", K_SMALL)
    with pytest.raises(ValueError, match=r"K: expected a \(3, 3\) camera matrix, got shape \(4, 4\)"):
        write_intrinsics(tmp_path / "intrinsics.xml", np.eye(4))
    assert not (tmp_path / "intrinsics.xml").exists()


@pytest.mark.parametrize("text, message", [
    ("0,10,20,1\n1,30,40,1\n", "first line '0,10,20,1' is a landmark, not a header"),  # lost landmark 0
    ("id,x,y,z,valid\n0,10,20,5,0\n", "expected the 4 fields 'id, x, y, valid', got 5"),  # z read as valid
    ("id,x,y,valid\n0,,20,0\n", "expected numbers"),  # the empty x was filled by y, y by valid...
    ("id,x,y,valid,score\n0,,20,0,0.9\n", "got 5"),  # ... and valid by the score: visible at (20, 0)
    ("id,x,y,valid\n0,10,20,nan\n", r"valid must be 0 or 1, got \[nan\]"),  # silently invisible
    ("id,x,y,valid\n0,10,20,2\n1,10,20,0.5\n", r"valid must be 0 or 1, got \[2.0, 0.5\] for ids \[0, 1\]"),
    ("id,x,y,valid\n1e30,10,20,1\n", "ids must be integers"),  # id -9223372036854775808
    ("id,y,x,valid\n0,20,10,1\n", "header 'id,y,x,valid' names the columns in another order"),  # x, y swapped
    ("x,y,id,valid\n10,20,0,1\n", "header .x,y,id,valid. names the columns in another order"),
    ("# X, Y, ID, valid\n10, 20, 0, 1\n", "names the columns in another order"),  # id 10 at (20, 0)
    ("id,row,col,valid\n0,20,10,1\n", "header 'id,row,col,valid' names the columns in another order"),  # (20, 10)
    ("id,v,u,valid\n0,20,10,1\n", "header 'id,v,u,valid' names the columns in another order"),  # (20, 10)
    ("id,y_px,x_px,valid\n0,20,10,1\n", "names the columns in another order"),  # a unit after the name
    ("id, Pixel Row, Pixel Col, valid\n0,20,10,1\n", "names the columns in another order"),
    ("id,y_coord,x_coord,valid\n0,20,10,1\n", "names the columns in another order"),
    ("id,x,y,occluded\n0,10,20,0\n1,30,40,1\n", "names a flag that is 1 where the landmark is hidden"),  # inverted
    ("# id, x, y, Hidden\n0,10,20,0\n", "names a flag that is 1 where the landmark is hidden"),
])
def test_landmark_csv_that_was_read_as_something_else(tmp_path, text, message):
    (tmp_path / "f.csv").write_text(text)
    with pytest.raises(ValueError, match="landmarks: .*f.csv: .*" + message):
        read_landmarks(tmp_path / "f.csv")


def test_landmark_csv_layouts_still_read(tmp_path):
    for text in ("# id, x, y, valid\n0, 245, 202, 1\n\n1\t3.5\t-1\t0\n", "id,x,y,valid\r\n0,245,202,1,\r\n1,3.5,-1,0\r\n",
                 "id, Column, Row, valid\n0,245,202,1\n1,3.5,-1,0\n", "id,u,v,valid\n0,245,202,1\n1,3.5,-1,0\n",
                 "id, x (px), y (px), v\n0,245,202,1\n1,3.5,-1,0\n"):  # v, last: a visibility flag
        (tmp_path / "f.csv").write_text(text)
        ids, xy, visible = read_landmarks(tmp_path / "f.csv")
        assert ids.tolist() == [0, 1] and xy.tolist() == [[245, 202], [3.5, -1]] and visible.tolist() == [True, False]


def test_write_landmarks_refuses_arrays_that_do_not_match(tmp_path):
    """Arrays of different lengths were cut to the shortest (3 landmarks written as 1), ids 0.5 and 1.7
    written as 0 and 1, a scalar visible flag a bare TypeError."""
    xy = np.array([[1.0, 2.0], [3.0, 4.0]])
    for ids, points, visible, message in (([0, 1, 2], xy[:1], [1, 1, 1], r"got shapes \(3,\), \(1, 2\) and \(3,\)"),
                                          ([0, 1], xy, True, r"got shapes \(2,\), \(2, 2\) and \(\)"),
                                          ([0.5, 1.7], xy, [1, 1], "ids must be integers")):
        with pytest.raises(ValueError, match="landmarks: .*w.csv: .*" + message):
            write_landmarks(tmp_path / "w.csv", ids, points, visible)
    assert not (tmp_path / "w.csv").exists()
    write_landmarks(tmp_path / "w.csv", np.arange(2.0), xy, np.array([True, False]))
    assert read_landmarks(tmp_path / "w.csv")[2].tolist() == [True, False]


@pytest.mark.parametrize("color, depth, kw, message", [
    (np.full((4, 5, 3), 100, np.uint8), np.full((4, 5), -1.0), {}, "negative values; use 0"),  # read back as 64.536 m
    (np.full((4, 5, 3), 100, np.uint8), np.full((4, 5), np.nan), {}, "NaN"),  # 0 after a RuntimeWarning
    (np.full((4, 5, 3), 0.5), np.ones((4, 5)), {}, "color: expected 8-bit values .*float64"),  # written black
    (np.ones((4, 5, 3), bool), np.ones((4, 5)), {}, "color: expected 8-bit values .*bool"),
    (np.full((4, 5, 3), 100, np.uint8), np.ones((8, 10)), {}, r"depth's \(H, W\) = \(8, 10\), got \(4, 5, 3\)"),
    (np.full((4, 5, 3), 100, np.uint8), np.ones((4, 5, 3)), {}, r"depth: expected an \(H, W\) array"),
    (np.full((4, 5, 5), 100, np.uint8), np.ones((4, 5)), {}, "got .4, 5, 5."),  # a bare cv2.error after the depth
    (np.full((4, 5, 3), 100, np.uint8), np.ones((4, 5)), {"depth_scale": -0.001}, "depth_scale: expected a positive"),
])
def test_write_frame_refuses_what_it_cannot_write_faithfully(tmp_path, color, depth, kw, message):
    with pytest.raises(ValueError, match=message):
        write_frame(tmp_path, "f", color, depth, **kw)
    assert not list(tmp_path.iterdir())  # nothing half written


def test_write_frame_writes_integer_colour_as_8_bit(tmp_path):
    write_frame(tmp_path, "f", np.full((4, 5, 3), 200), np.ones((4, 5)))
    assert cv2.imread(str(tmp_path / "f-rgb.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint8
    assert geofeat.io.read_image(tmp_path / "f-rgb.png").max() == 200


def test_a_skipped_frame_is_named_once(tmp_path):
    """The commands' SKIPPED lines: an error from `Sequence.frame` already names the frame and its
    folder, and was printed as 'SKIPPED frame frame-001: frame frame-001 of ...'."""
    from geofeat.io import skipped_frame_line

    folder = _small_sequence(tmp_path / "seq")
    cv2.imwrite(str(folder / "frame-001-depth.png"), np.zeros((120, 160), np.uint16))
    with pytest.raises(ValueError) as error:
        geofeat.read_sequence(folder).frame("frame-001")
    line = skipped_frame_line("frame-001", error.value, "seq")
    assert line.startswith("SKIPPED frame frame-001 of ") and line.count("frame-001") == 1, line
    assert skipped_frame_line("f2", ValueError("no keypoints detected (sift)"), "seq") == \
        "SKIPPED frame f2 of seq: no keypoints detected (sift)"
    assert skipped_frame_line("f2", KeyError()) == "SKIPPED frame f2: KeyError"


def _flat_sequence(folder, depth_m):
    """Two frames of the shipped colour at a constant depth, written as millimetre PNGs."""
    frame = geofeat.read_demo_frame()
    folder.mkdir(parents=True)
    write_intrinsics(folder / "intrinsics.xml", frame.K)
    for name in ("a-ref", "b"):
        write_frame(folder, name, frame.color, np.where(frame.depth > 0, depth_m, 0.0))
    return folder


def test_depth_ten_times_too_near_is_warned_of_once_per_sequence(tmp_path):
    """`--depth-scale 0.0001` on millimetre PNGs (or PNGs written 10x too small) gave a scene at 0.1 m
    without a word: plausible enough to pass, but most likely wrong units."""
    import warnings

    from geofeat.inputs import DepthUnitsWarning

    near = _flat_sequence(tmp_path / "near", 0.1)
    with pytest.warns(DepthUnitsWarning, match=r"sequence .*near.*median depth 0\.1 m .*--depth-scale") as caught:
        seq = geofeat.read_sequence(near)
        geofeat.read_sequence(near)  # the same sequence again: no second warning
        seq.frame("b")
    assert len([w for w in caught if w.category is DepthUnitsWarning]) == 1
    assert seq.frame("b").depth.max() == pytest.approx(0.1)  # a warning, never an error
    normal = _flat_sequence(tmp_path / "normal", 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DepthUnitsWarning)
        geofeat.read_sequence(normal)
        geofeat.read_demo_frame()
        with pytest.warns(DepthUnitsWarning, match=r"median depth 0\.1 m at depth scale 0\.0001"):
            geofeat.read_sequence(normal, depth_scale=0.0001)  # millimetres read as tenths of one
        with pytest.warns(DepthUnitsWarning, match=r"median depth 25 m .*farther"):
            geofeat.read_sequence(_flat_sequence(tmp_path / "far", 2.5), depth_scale=0.01)


def test_the_command_line_shows_the_depth_units_warning_on_one_line(tmp_path, capsys, monkeypatch):
    import sys
    import warnings

    from geofeat.cli import main

    def show(message, category, filename, lineno, file=None, line=None):  # Python's own, outside pytest's recorder
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    folder = _flat_sequence(tmp_path / "s", 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        monkeypatch.setattr(warnings, "showwarning", show)
        assert main(["extract", str(folder), "--descriptor", "orb", "--keypoints", "50", "--depth-scale", "0.0001",
                     "--out", str(tmp_path / "f.h5")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(err) == 1 and err[0].startswith(f"geofeat extract: warning: sequence {folder} "), err
    assert "median depth 0.1 m" in err[0] and "--depth-scale" in err[0]


# ---------------------------------------------------------------- review-io: frames, colour, csv headers
def test_frames_are_in_natural_order_and_hidden_files_are_not_frames(tmp_path):
    """`frame-10` came before `frame-2` (tracking jumped through the sequence), and macOS's `._` resource
    forks (copying to a USB disk) were frames: `._frame-001-rgb.png` sorted first, became the reference,
    and the whole sequence was refused as an undecodable image."""
    from geofeat.io import find_sequences

    folder = _small_sequence(tmp_path / "seq")
    for name in ("frame-10", "frame-2"):
        for suffix in ("-rgb.png", "-depth.png"):
            shutil.copy(folder / f"frame-001{suffix}", folder / f"{name}{suffix}")
    for suffix in ("-rgb.png", "-depth.png"):
        (folder / f"._frame-001{suffix}").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    seq = geofeat.read_sequence(folder)
    assert seq.names == ["frame-000-master", "frame-001", "frame-2", "frame-10"]
    assert find_sequences(tmp_path) == [folder]


def test_a_folder_of_sequences_with_loose_frames_beside_them_is_refused(tmp_path):
    """find_sequences took a folder holding sequence folders and a few loose frames for one sequence
    (of the loose frames), and left the sequence folders out without a word."""
    from geofeat.io import find_sequences

    data = tmp_path / "data"
    folder = _small_sequence(data / "a")
    for suffix in ("-rgb.png", "-depth.png"):
        shutil.copy(folder / f"frame-001{suffix}", data / f"stray{suffix}")
    with pytest.raises(ValueError, match=r"--data: .*data holds both frames \(stray-rgb.png\) and the sequence "
                                         r"folders a"):
        find_sequences(data, what="--data")
    assert find_sequences(folder) == [folder]


@pytest.mark.parametrize("change", ["jpeg", "upper-case", "depth-only"])
def test_a_sequence_folder_whose_frames_are_not_read_is_refused_not_left_out(tmp_path, change):
    """A folder of sequences where one sequence's colour frames were JPEG (or .PNG, or gone): that
    sequence was passed over without a word, and bench, track and train ran on the others as if they
    were the whole dataset."""
    from geofeat.io import find_sequences

    data = tmp_path / "data"
    good = _small_sequence(data / "a")
    bad = _small_sequence(data / "b")
    for name in ("frame-000-master", "frame-001"):
        colour = bad / f"{name}-rgb.png"
        if change == "jpeg":
            cv2.imwrite(str(bad / f"{name}-rgb.jpg"), cv2.imread(str(colour)))
            colour.unlink()
        elif change == "upper-case":
            colour.rename(bad / f"{name}-rgb.PNG")
        else:
            colour.unlink()
    with pytest.raises(ValueError, match=r"--data: .*data/b holds no '\*-rgb.png' frames, though it looks like a "
                                         r"sequence folder"):
        find_sequences(data, what="--data")
    (data / "notes").mkdir()  # a folder that is no sequence attempt (results, notes) is still passed over
    (data / "notes" / "table.md").write_text("x")
    shutil.rmtree(bad)
    assert find_sequences(data) == [good]


@pytest.mark.parametrize("colour, depth", [("frame-002-rgb.PNG", "frame-002-depth.PNG"),
                                          ("frame-002-RGB.png", "frame-002-DEPTH.png"), ("frame-002-rgb.jpg", None),
                                          ("frame-002_rgb.png", "frame-002_depth.png")])
def test_a_frame_of_a_read_sequence_saved_under_another_extension_is_refused_not_left_out(tmp_path, colour, depth):
    """One frame of a sequence saved as `.PNG` (or `-RGB.png`; or as `.jpg` without its depth), beside
    frames read: `read_sequence` read the others and left that frame out without a word, so `track`
    jumped over it and `bench` scored one pair fewer."""
    folder = _small_sequence(tmp_path / "seq")
    image = cv2.imread(str(folder / "frame-001-rgb.png"))
    cv2.imwrite(str(folder / colour), image)
    if depth is not None:
        shutil.copy(folder / "frame-001-depth.png", folder / depth)
    with pytest.raises(ValueError, match=rf"folder: .*seq holds colour frames geofeat does not read \({colour}\) "
                                         r"beside its '\*-rgb.png' frames"):
        geofeat.read_sequence(folder)
    (folder / colour).unlink()
    cv2.imwrite(str(folder / "frame-001-rgb.jpg"), image)  # a copy of a frame read (a preview) leaves nothing out
    assert geofeat.read_sequence(folder).names == ["frame-000-master", "frame-001"]


@pytest.mark.parametrize("key", ["depthScale", "depth_unit", "scale", "depth-scale", "Radius_m"])
def test_geofeat_json_key_misspelt_is_refused(tmp_path, key):
    """{"depthScale": 0.0001} was ignored: 0.1 mm depth read as millimetres, a scene at 1 m at 10 m,
    plausible and not warned of."""
    folder = _small_sequence(tmp_path / "seq")
    (folder / "geofeat.json").write_text(json.dumps({key: 0.0001, "comment": "kept"}))
    with pytest.raises(ValueError, match=f"geofeat.json: unknown key '{key}'; geofeat reads depth_scale"):
        geofeat.read_sequence(folder)
    (folder / "geofeat.json").write_text(json.dumps({"depth_scale": 0.001, "comment": "kept", "camera": "kinect"}))
    assert geofeat.read_sequence(folder).depth_scale == 0.001


def test_timestamp_frame_names_are_in_time_order(tmp_path):
    """Frames named by timestamps with fractional seconds of varying length (str(float) of a ROS time)
    were ordered by the digits after the point as a whole number: 0.1 s before 0.0333 s before 0.0667 s."""
    from geofeat.io import frame_names, natural_key

    times = ["1650000000.0", "1650000000.0333333", "1650000000.0666667", "1650000000.1", "1650000000.1333333",
             "1650000001.0", "1650000010.5"]
    for t in reversed(times):
        (tmp_path / f"{t}-rgb.png").write_bytes(b"")
    assert frame_names(tmp_path) == times
    names = ["frame-10", "frame-2", "frame-1", "frame-0010b", "cloud_ref"]
    assert sorted(names, key=natural_key) == ["cloud_ref", "frame-1", "frame-2", "frame-10", "frame-0010b"]


def test_a_depth_png_without_its_colour_is_refused(tmp_path):
    """A frame whose `-rgb.png` was missing was left out without a word (the converse was refused)."""
    folder = _small_sequence(tmp_path / "seq")
    shutil.copy(folder / "frame-001-depth.png", folder / "frame-002-depth.png")
    with pytest.raises(ValueError, match=r"folder: frames without '-rgb.png' in .*seq: \['frame-002'\]"):
        geofeat.read_sequence(folder)


def test_a_16bit_colour_png_of_8bit_values_warns_naming_the_file(tmp_path):
    """Such a PNG was read as 0-65535 and kept to its high byte: a black image (SIFT found nothing, the
    frame was skipped as having no keypoints) without a word on why."""
    from geofeat.io import read_image

    color = cv2.imread(str(demo_data_dir() / "cloud_1-rgb.png"))
    cv2.imwrite(str(tmp_path / "low-rgb.png"), color.astype(np.uint16))
    with pytest.warns(UserWarning, match=r"rgb_path: .*low-rgb.png: nearly black .* 8-bit values in a uint16"):
        read_image(tmp_path / "low-rgb.png")
    cv2.imwrite(str(tmp_path / "full-rgb.png"), color.astype(np.uint16) * 257)  # a true 16-bit PNG reads as before
    np.testing.assert_array_equal(read_image(tmp_path / "full-rgb.png"), color)


def test_landmarks_missing_for_some_frames_are_named(tmp_path, capsys):
    """With a csv for the reference but not for a target, `match` said 'ground truth: none' and `bench`
    'no csv landmarks': the user's landmarks were set aside without saying which file was missing."""
    from geofeat.cli import main
    from geofeat.groundtruth.sources import GroundTruth

    folder = _small_sequence(tmp_path / "seq")
    write_landmarks(folder / "frame-000-master.csv", [0], np.array([[10.0, 20.0]]), [1])
    with pytest.raises(ValueError, match=r"no ground truth \(no simulator files, csv landmarks in 1 of 2 frames only, "
                                         r"none for frame-001, no TPS files\)"):
        GroundTruth(geofeat.read_sequence(folder), None)
    with pytest.warns(UserWarning, match="none for frame-001, no TPS files.; matches are written without being judged"):
        assert main(["match", str(folder), "--descriptor", "orb", "--keypoints", "50", "--out", str(tmp_path / "m")]) == 0


# ---------------------------------------------------------------- review-newuser: a folder in another layout
def _renamed(folder, rename):
    """`rename(path) -> new name or None` applied to every file of `folder` (None: removed)."""
    for path in sorted(folder.iterdir()):
        new = rename(path)
        if new is None:
            path.unlink()
        elif new != path.name:
            path.rename(folder / new)
    return folder


def _colour_as_jpeg(folder):
    for name in ("frame-000-master", "frame-001"):
        cv2.imwrite(str(folder / f"{name}-rgb.jpg"), cv2.imread(str(folder / f"{name}-rgb.png")))
        (folder / f"{name}-rgb.png").unlink()


def _plain_numbers(folder):
    _renamed(folder, lambda p: None if p.name.endswith("-depth.png") else p.name)
    for i, p in enumerate(sorted(folder.glob("*-rgb.png")), 1):
        p.rename(folder / f"{i}.png")


def _subfolders(folder):
    for kind in ("rgb", "depth"):
        (folder / kind).mkdir()
        for p in folder.glob(f"*-{kind}.png"):
            p.rename(folder / kind / p.name.replace(f"-{kind}", ""))


@pytest.mark.parametrize("change, found", [
    (_colour_as_jpeg, r"found frame-000-master-rgb.jpg, frame-001-rgb.jpg: colour frames must be PNG files named "
                      r"exactly <name>-rgb.png"),
    (lambda f: _renamed(f, lambda p: p.name.replace(".png", ".PNG")), r"found frame-000-master-rgb.PNG, frame-001-rgb.PNG"),
    (_plain_numbers, r"found images not named <name>-rgb.png \(1.png, 2.png\)"),
    (_subfolders, r"found sub-folders \(depth, rgb\) but no sequence one level down"),
    (lambda f: _renamed(f, lambda p: None), "the folder is empty"),
], ids=["jpeg-colour", "upper-case-extension", "plain-numbers", "rgb-and-depth-sub-folders", "empty"])
def test_a_folder_without_frames_says_what_it_holds_and_the_layout(tmp_path, change, found):
    """A robotics user's own recording (JPEG colour, 1.png ... 10.png, rgb/ and depth/ folders) was
    refused as "no '*-rgb.png' frames in FOLDER", which names neither what geofeat found there nor the
    layout it reads, nor how to write that layout from arrays."""
    from geofeat.io import find_sequences

    folder = _small_sequence(tmp_path / "seq")
    change(folder)
    layout = r"a sequence folder holds <name>-rgb.png \(8-bit colour\), <name>-depth.png .* geofeat.write_frame"
    with pytest.raises(ValueError, match=rf"folder: no '\*-rgb.png' frames in .*seq: {found}.*; {layout}"):
        geofeat.read_sequence(folder)
    with pytest.raises(ValueError, match=rf"--data: no sequence \(folder of '\*-rgb.png' frames\) in .*seq: {found}"):
        find_sequences(folder, what="--data")


@pytest.mark.parametrize("suffix", [".tiff", ".npy"])
def test_depth_saved_in_another_format_is_named_with_the_fix(tmp_path, suffix):
    """Depth in metres as a float TIFF or a .npy beside the colour: "frames without '-depth.png'" named
    neither the file found nor what depth geofeat reads."""
    folder = _small_sequence(tmp_path / "seq")
    for name in ("frame-000-master", "frame-001"):
        metres = read_depth(folder / f"{name}-depth.png")
        (folder / f"{name}-depth.png").unlink()
        if suffix == ".npy":
            np.save(folder / f"{name}-depth.npy", metres)
        else:
            cv2.imwrite(str(folder / f"{name}-depth{suffix}"), metres)
    with pytest.raises(ValueError, match=rf"frames without '-depth.png' in .*\['frame-000-master', 'frame-001'\] \(found "
                                         rf"frame-000-master-depth{suffix}, frame-001-depth{suffix}: depth must be a "
                                         r"16-bit PNG.*geofeat.write_frame\(folder, name, color, depth_m\)"):
        geofeat.read_sequence(folder)
    if suffix == ".npy":
        with pytest.raises(ValueError, match=r"cannot decode image .*\.npy; for depth as an array \(np.load\), build the "
                                             r"frame with geofeat.RGBDFrame\(image, depth_m, K\)"):
            read_depth(folder / "frame-001-depth.npy")


@pytest.mark.parametrize("name, save", [
    ("intrinsics.txt", lambda p: np.savetxt(p, K_SMALL)),
    ("intrinsics.npy", lambda p: np.save(p, K_SMALL)),
    ("K.yml", lambda p: write_intrinsics(p, K_SMALL)),
])
def test_intrinsics_saved_in_another_format_are_named_with_the_fix(tmp_path, name, save):
    """A K saved as text or NumPy beside the frames: the sequence said "file not found: intrinsics.xml",
    and read_frame on the file itself "cannot parse ... as OpenCV FileStorage (<class 'cv2.FileStorage'>
    returned a result with an exception set)"; neither said how to make a file geofeat reads."""
    folder = _small_sequence(tmp_path / "seq")
    (folder / "intrinsics.xml").unlink()
    save(folder / name)
    fix = r"geofeat.write_intrinsics\(path, K\), or build the frame with geofeat.RGBDFrame\(image, depth_m, K\)"
    with pytest.raises(ValueError, match=rf"intrinsics_path: file not found: .*intrinsics.xml \(found {name}\); .*{fix}"):
        geofeat.read_sequence(folder)
    if not name.endswith(".yml"):  # a YAML FileStorage is read as it is
        with pytest.raises(ValueError, match=rf"cannot parse .*{name} as OpenCV FileStorage; .*{fix}") as error:
            read_intrinsics(folder / name)
        assert "exception set" not in str(error.value)


def test_a_folder_of_sequences_given_for_one_sequence_names_them(tmp_path):
    """`geofeat extract DATASET` (a folder of sequences) was "no '*-rgb.png' frames in DATASET"."""
    _small_sequence(tmp_path / "data" / "cloth")
    with pytest.raises(ValueError, match=r"no '\*-rgb.png' frames in .*data: it holds the sequence folders cloth: name "
                                         r"one of them"):
        geofeat.read_sequence(tmp_path / "data")


def test_intrinsics_under_another_node_name_it(tmp_path):
    """`camera_matrix` (OpenCV's calibration sample) instead of `intrinsics`: the error said the node
    was missing, not which nodes the file holds."""
    fs = cv2.FileStorage(str(tmp_path / "intrinsics.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K_SMALL)
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    with pytest.raises(ValueError, match=r"no 3x3 matrix under the node 'intrinsics' \(its nodes: camera_matrix, "
                                         r"distortion_coefficients; rename"):
        read_intrinsics(tmp_path / "intrinsics.xml")


@pytest.mark.parametrize("text", [
    '<?xml version="1.0"?>\n<opencv_storage>\n<fx>525.</fx><fy>524.5</fy><cx>319.5</cx><cy>239.5</cy>\n</opencv_storage>\n',
    "%YAML:1.0\n---\nCamera.fx: 525.0\nCamera.fy: 524.5\nCamera.cx: 319.5\nCamera.cy: 239.5\nCamera.k1: 0.0\n",
])
def test_intrinsics_as_single_numbers_say_how_to_write_the_matrix(tmp_path, text):
    """fx, fy, cx, cy as single nodes (as ORB-SLAM's settings hold them): the error advised renaming
    "the camera matrix's" node to 'intrinsics', and the file holds no matrix to rename."""
    (tmp_path / "intrinsics.xml").write_text(text)
    with pytest.raises(ValueError, match=r"intrinsics.xml holds fx, fy, cx, cy as single numbers, not the 3x3 matrix "
                                         r".*write_intrinsics\(path, \[\[525, 0, 319.5\], \[0, 524.5, 239.5\], "
                                         r"\[0, 0, 1\]\]\)") as error:
        read_intrinsics(tmp_path / "intrinsics.xml")
    assert "rename" not in str(error.value)


def test_an_exif_orientation_tag_does_not_turn_the_colour_away_from_its_depth(tmp_path):
    """OpenCV's imread turns a PNG by its EXIF orientation tag (an eXIf chunk, kept by photo tools and by
    PIL's save(exif=...)): the colour of a frame was read rotated 180 degrees against its depth, its
    intrinsics and its landmarks, all of which are in the stored pixels, and the frame read without a
    word. The readers keep the stored pixels, as PIL and NumPy give them."""
    from PIL import Image

    from geofeat.io import read_image

    src = demo_data_dir()
    color = cv2.imread(str(src / "cloud_1-rgb.png"), cv2.IMREAD_COLOR)
    exif = Image.Exif()
    exif[0x0112] = 3  # orientation: rotate 180 degrees
    Image.fromarray(color[:, :, ::-1]).save(tmp_path / "tagged-rgb.png", exif=exif.tobytes())
    np.testing.assert_array_equal(read_image(tmp_path / "tagged-rgb.png"), color)
    depth = cv2.imread(str(src / "cloud_1-depth.png"), cv2.IMREAD_UNCHANGED)
    Image.fromarray(depth).save(tmp_path / "tagged-depth.png", exif=exif.tobytes())
    np.testing.assert_array_equal(read_depth(tmp_path / "tagged-depth.png"), depth.astype(np.float32) * np.float32(0.001))
    frame = geofeat.read_frame(tmp_path / "tagged-rgb.png", src / "cloud_1-depth.png", src / "intrinsics.xml")
    np.testing.assert_array_equal(frame.color, color)


def test_tenth_millimetre_depth_read_as_millimetres_is_warned_of(tmp_path):
    """`simulate` writes its depth PNGs in 0.1 mm and says so in geofeat.json; frames copied without
    that file (or any 0.1 mm PNGs) were read as millimetres: the cloth at 0.48-1.03 m (the nearest and
    farthest references of the mild, paper and hard presets) lay 4.8-10.3 m away, every geodesic patch
    a tenth of its size, without a word (the warning began at 20 m)."""
    import warnings

    from geofeat.inputs import DepthUnitsWarning

    for metres in (0.48, 1.03):
        folder = tmp_path / f"sim-{metres}"
        folder.mkdir()
        frame = geofeat.read_demo_frame()
        write_intrinsics(folder / "intrinsics.xml", frame.K)
        for name in ("a-ref", "b"):  # as `simulate` writes them, less its geofeat.json
            write_frame(folder, name, frame.color, np.where(frame.depth > 0, metres, 0.0), depth_scale=0.0001)
        (folder / "geofeat.json").unlink()  # write_frame records the scale there
        with pytest.warns(DepthUnitsWarning, match=rf"median depth {metres * 10:.3g} m .*farther"):
            geofeat.read_sequence(folder)
        (folder / "geofeat.json").write_text(json.dumps({"depth_scale": 0.0001}))
        with warnings.catch_warnings():
            warnings.simplefilter("error", DepthUnitsWarning)
            assert geofeat.read_sequence(folder).depth_scale == 0.0001
    with warnings.catch_warnings():  # a real sensor's far range (a Kinect v1 sees to about 4 m) is not warned of
        warnings.simplefilter("error", DepthUnitsWarning)
        geofeat.read_sequence(_flat_sequence(tmp_path / "far-kinect", 3.5))


def test_depth_in_the_tum_benchmarks_units_read_as_millimetres_is_told_its_own_reading(tmp_path):
    """Depth PNGs of 5000 units a metre (TUM RGB-D, ICL-NUIM, ETH3D SLAM) read as millimetres put the
    Kinect frame's cloth (median 0.98 m) at 4.89 m; the warning's only reading was tenths of a millimetre,
    0.49 m, and with depth_scale=0.0001 the sequence was read at half its depth without another word."""
    from geofeat.inputs import DepthUnitsWarning

    src = demo_data_dir()
    metres = read_depth(src / "cloud_1-depth.png")
    cv2.imwrite(str(tmp_path / "cloud_1-depth.png"), np.rint(metres * 5000).astype(np.uint16))
    for name in ("cloud_1-rgb.png", "intrinsics.xml"):
        shutil.copy(src / name, tmp_path / name)
    with pytest.warns(DepthUnitsWarning, match=r"median depth 4.89 m .*farther than usual.*as fifths of a millimetre "
                                               r"\(5000 a metre, as TUM RGB-D stores depth\) 0.98 m \(depth_scale=0.0002\)"):
        geofeat.read_sequence(tmp_path)


@pytest.mark.parametrize("text", ["", "\n\n", " \t\n"])
def test_an_empty_landmark_csv_is_refused_not_read_as_no_landmarks(tmp_path, text):
    """A csv cut to nothing (a failed copy) read as a frame with no landmarks: bench --protocol landmarks
    skipped each of its pairs as "no landmark id visible in both", and the sequence's score was
    the mean over the other pairs. A header line alone is a frame without landmarks."""
    path = tmp_path / "frame-001.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"landmarks: .*frame-001.csv: the file is empty; expected a header line"):
        read_landmarks(path)
    path.write_text("id,x,y,valid\n")
    ids, xy, visible = read_landmarks(path)
    assert ids.shape == (0,) and xy.shape == (0, 2) and visible.shape == (0,)


def test_a_depth_png_read_as_8_bits_is_not_taken_for_metres(tmp_path):
    """`cv2.imread(depth_png, cv2.IMREAD_GRAYSCALE)` keeps the high byte of millimetres: the Kinect
    frame's 0.7-1.1 m became 2-4, and RGBDFrame took that for metres without a word (write_frame wrote
    it as 2-4 mm)."""
    src = demo_data_dir()
    image = cv2.imread(str(src / "cloud_1-rgb.png"))
    depth8 = cv2.imread(str(src / "cloud_1-depth.png"), cv2.IMREAD_GRAYSCALE)
    assert depth8.dtype == np.uint8 and 2 <= np.median(depth8[depth8 > 0]) <= 4  # plausible as metres
    K = read_intrinsics(src / "intrinsics.xml")
    with pytest.raises(ValueError, match=r"depth: 8-bit values \(uint8\) are no depth in metres.*read_depth"):
        geofeat.RGBDFrame(image, depth8, K)
    with pytest.raises(ValueError, match=r"depth: 8-bit values"):
        write_frame(tmp_path, "f", image, depth8)
    assert not list(tmp_path.iterdir())
    frame = geofeat.RGBDFrame(image, read_depth(src / "cloud_1-depth.png"), K)  # the reader's metres
    assert 0.6 < np.median(frame.depth[frame.depth > 0]) < 1.2


@pytest.mark.parametrize("node, held", [
    ('<intrinsics>525 0 319.5 0 525 239.5 0 0 1</intrinsics>', "a plain sequence of 9 values"),
    ('<intrinsics type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt><data>525 0 319.5 0 525 239.5 0 0'
     '</data></intrinsics>', "an opencv-matrix whose data does not match its rows, cols and dt"),
    ('<intrinsics type_id="opencv-matrix"><rows>3</rows><cols>4</cols><dt>d</dt><data>525 0 319.5 0 0 525 239.5 0 0 0 '
     '1 0</data></intrinsics>', "a 3x4 matrix"),
    ("%YAML:1.0\n---\nintrinsics: [[525, 0, 319.5], [0, 525, 239.5], [0, 0, 1]]\n", "a plain sequence of 3 rows"),
    ("%YAML:1.0\n---\nintrinsics:\n  rows: 3\n  cols: 3\n  data: [525, 0, 319.5, 0, 525, 239.5, 0, 0, 1]\n",
     r"a map of rows, cols, data \(an opencv-matrix has rows, cols, dt and data\)"),  # ROS's camera_info
])
def test_an_intrinsics_node_that_is_no_3x3_matrix_says_what_it_holds(tmp_path, node, held):
    """A hand-written node 'intrinsics' (nine plain numbers, a value short, a 3x4 projection matrix) was
    "no 3x3 matrix under the node 'intrinsics' (its nodes: intrinsics; rename the camera matrix's to
    'intrinsics')": advice to rename the node to the name it has."""
    text = node if node.startswith("%YAML") else f'<?xml version="1.0"?>\n<opencv_storage>\n{node}\n</opencv_storage>\n'
    (tmp_path / "intrinsics.xml").write_text(text)
    with pytest.raises(ValueError, match=rf"intrinsics.xml: its node 'intrinsics' holds {held}.*not a 3x3 "
                                         r"opencv-matrix; .*write_intrinsics") as error:
        read_intrinsics(tmp_path / "intrinsics.xml")
    assert "rename" not in str(error.value)


def test_lens_distortion_beside_the_intrinsics_is_not_dropped_without_a_word(tmp_path):
    """OpenCV's calibration output with its `camera_matrix` renamed to `intrinsics` (as the error for
    that file advises) keeps `distortion_coefficients`: geofeat projects as a pinhole and ignored them
    without a word (k1 = 0.2 moves a VGA corner by tens of pixels)."""
    src = demo_data_dir()
    K = read_intrinsics(src / "intrinsics.xml")
    for name, coefficients, warned in (("distortion_coefficients", [[0.2, -0.5, 0.001, 0.0, 0.3]], True),
                                       ("D", [[0.0, 0.0, 0.0, 0.0, 0.0]], False)):  # undistorted: nothing to say
        fs = cv2.FileStorage(str(tmp_path / "intrinsics.xml"), cv2.FILE_STORAGE_WRITE)
        fs.write("intrinsics", K)
        fs.write(name, np.array(coefficients))
        fs.release()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            frame = geofeat.read_frame(src / "cloud_1-rgb.png", src / "cloud_1-depth.png", tmp_path / "intrinsics.xml")
        np.testing.assert_array_equal(frame.K, K)
        messages = [str(w.message) for w in caught if "distortion" in str(w.message)]
        assert len(messages) == warned
        if warned:
            assert re.search(r"intrinsics.xml holds lens distortion coefficients \(node 'distortion_coefficients': "
                             r"\[0.2, -0.5, 0.001, 0.0, 0.3\]\), which geofeat does not apply.*Undistort", messages[0])
    text = "%YAML:1.0\n---\nintrinsics: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [525, 0, 319.5, 0, 525, " \
           "239.5, 0, 0, 1]\ndist_coeffs: [[0.1, 0.0, 0.0, 0.0, 0.0]]\n"  # a hand-written YAML list of rows
    (tmp_path / "intrinsics.xml").write_text(text)
    with pytest.warns(UserWarning, match=r"distortion coefficients \(node 'dist_coeffs': \[0.1, 0.0, 0.0, 0.0, 0.0\]\)"):
        read_intrinsics(tmp_path / "intrinsics.xml")


@pytest.mark.parametrize("extra, node, values", [
    ("<k1>0.2</k1><k2>-0.5</k2><p1>0.001</p1><p2>0.</p2>", "nodes 'k1, k2, p1, p2'", r"\[0.2, -0.5, 0.001, 0.0\]"),
    ('<kc type_id="opencv-matrix"><rows>5</rows><cols>1</cols><dt>d</dt><data>0.2 -0.5 0 0 0</data></kc>', "node 'kc'",
     r"\[0.2, -0.5, 0.0, 0.0, 0.0\]"),  # the MATLAB calibration toolbox's name
])
def test_lens_distortion_as_single_numbers_or_under_kc_is_not_dropped_without_a_word(tmp_path, extra, node, values):
    """Coefficients written one number a node (`k1`, `k2`, `p1`, `p2`, as ORB-SLAM's and Kalibr's settings
    hold them) or under `kc` beside the camera matrix were ignored without the warning a `D` node gets."""
    matrix = ('<intrinsics type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt><data>525 0 319.5 0 525 '
              '239.5 0 0 1</data></intrinsics>')
    path = tmp_path / "intrinsics.xml"
    path.write_text(f'<?xml version="1.0"?>\n<opencv_storage>\n{matrix}\n{extra}\n</opencv_storage>\n')
    with pytest.warns(UserWarning, match=rf"intrinsics.xml holds lens distortion coefficients \({node}: {values}\), "
                                         "which geofeat does not apply"):
        K = read_intrinsics(path)
    assert K[0, 0] == 525.0
    path.write_text(f'<?xml version="1.0"?>\n<opencv_storage>\n{matrix}\n<k1>0.</k1><k2>0</k2>\n</opencv_storage>\n')
    with warnings.catch_warnings():  # zero coefficients: undistorted frames, nothing to say
        warnings.simplefilter("error")
        read_intrinsics(path)


def test_a_byte_swapped_depth_png_is_refused_not_read_as_noise(tmp_path):
    """16-bit depth written least significant byte first (raw little-endian bytes into a PNG, which is
    big-endian) read as noise with a plausible median: the Kinect frame's 0.7-1.1 m became 0-65 m,
    median 48.6 m, and `read_sequence` only warned that it was farther than usual."""
    src = demo_data_dir()
    raw = cv2.imread(str(src / "cloud_1-depth.png"), cv2.IMREAD_ANYDEPTH)
    cv2.imwrite(str(tmp_path / "cloud_1-depth.png"), raw.byteswap())
    for name in ("cloud_1-rgb.png", "intrinsics.xml"):
        shutil.copy(src / name, tmp_path / name)
    message = r"depth_path: .*cloud_1-depth.png: its 16-bit values are a depth map only with their two bytes swapped"
    with pytest.raises(ValueError, match=message):
        geofeat.read_sequence(tmp_path)
    with pytest.raises(ValueError, match=message):
        read_depth(tmp_path / "cloud_1-depth.png")
    cv2.imwrite(str(tmp_path / "cloud_1-depth.png"), raw)  # as stored: read, and the same as the shipped file
    np.testing.assert_array_equal(read_depth(tmp_path / "cloud_1-depth.png"), read_depth(src / "cloud_1-depth.png"))


def test_depth_pixels_at_the_16_bit_maximum_are_read_as_missing(tmp_path):
    """A sensor's no-data code 65535 was read as 65.5 m: with most of the frame valid the median passed,
    and the smoothing mixed those pixels into the surface beside them (17 % of the Kinect frame's mesh
    off by over 1 cm, up to 54 m)."""
    src = demo_data_dir()
    raw = cv2.imread(str(src / "cloud_1-depth.png"), cv2.IMREAD_UNCHANGED)
    coded = np.where(raw > 0, raw, 65535).astype(np.uint16)
    folder = tmp_path / "seq"
    folder.mkdir()
    for name in ("a", "b"):
        cv2.imwrite(str(folder / f"{name}-depth.png"), coded)
    with pytest.warns(UserWarning, match=r"a-depth.png: \d+ pixels \(1\d\.\d%\) hold 65535.*not a depth of 65.5\d m; "
                                         r"read as missing") as caught:
        depth = read_depth(folder / "a-depth.png")
        read_depth(folder / "b-depth.png")  # once per folder
    assert sum("65535" in str(w.message) for w in caught) == 1
    np.testing.assert_array_equal(depth, read_depth(src / "cloud_1-depth.png"))
    frame = geofeat.read_frame(src / "cloud_1-rgb.png", folder / "a-depth.png", src / "intrinsics.xml")
    assert frame.depth.max() < 1.2


def test_a_transposed_camera_matrix_is_named_as_such(tmp_path):
    """MATLAB's IntrinsicMatrix is K transposed: the errors said only that the last row must be
    [0, 0, 1], not that K.T is the camera matrix."""
    src = demo_data_dir()
    K = read_intrinsics(src / "intrinsics.xml")
    image, depth = cv2.imread(str(src / "cloud_1-rgb.png")), read_depth(src / "cloud_1-depth.png")
    with pytest.raises(ValueError, match=r"K: last row must be \[0, 0, 1\], got .*; it is a camera matrix transposed "
                                         r"\(as MATLAB's IntrinsicMatrix is\): use K.T"):
        geofeat.RGBDFrame(image, depth, K.T)
    write_intrinsics(tmp_path / "intrinsics.xml", K.T)
    with pytest.raises(ValueError, match=r"intrinsics.xml: expected \[\[fx, s, cx\].*got rows .*; it is a camera "
                                         r"matrix transposed"):
        geofeat.read_frame(src / "cloud_1-rgb.png", src / "cloud_1-depth.png", tmp_path / "intrinsics.xml")
    with pytest.raises(ValueError, match=r"K: last row must be \[0, 0, 1\], got \[0.0, 0.0, 2.0\]$"):  # no such hint
        geofeat.RGBDFrame(image, depth, K * [[1], [1], [2]])


def test_write_frame_at_another_depth_scale_is_read_back_in_metres(tmp_path):
    """write_frame(..., depth_scale=0.0001) wrote 0.1 mm PNGs into a folder read as millimetres: the
    frame came back 10x too far (a scene at 0.4 m as 4 m, without even the far-depth warning)."""
    src = demo_data_dir()
    image, depth = cv2.imread(str(src / "cloud_1-rgb.png")), read_depth(src / "cloud_1-depth.png")
    seq = tmp_path / "seq"
    seq.mkdir()
    write_intrinsics(seq / "intrinsics.xml", read_intrinsics(src / "intrinsics.xml"))
    (seq / "geofeat.json").write_text(json.dumps({"radius": 0.05}))
    write_frame(seq, "f-master", image, depth, depth_scale=0.0001)
    assert json.loads((seq / "geofeat.json").read_text()) == {"radius": 0.05, "depth_scale": 0.0001}
    write_frame(seq, "f-1", image, depth, depth_scale=0.0001)
    frame = geofeat.read_sequence(seq).frame("f-1")
    np.testing.assert_allclose(frame.depth, depth, atol=1e-4)
    with pytest.raises(ValueError, match=r"depth_scale: 0.001 m per unit, but the depth PNGs of .*seq are read at "
                                         r"0.0001 \(its geofeat.json's depth_scale\); a sequence folder has one"):
        write_frame(seq, "f-2", image, depth)
    mm = tmp_path / "mm"
    mm.mkdir()
    write_frame(mm, "a", image, depth)
    assert not (mm / "geofeat.json").exists()  # the default needs none
    with pytest.raises(ValueError, match=r"read at 0.001 \(millimetres, as its depth PNGs a-depth.png are read without"):
        write_frame(mm, "b", image, depth, depth_scale=0.0001)
    assert sorted(p.name for p in mm.iterdir()) == ["a-depth.png", "a-rgb.png"]
    far = depth.copy()
    far[0, 0] = 65.535
    with pytest.raises(ValueError, match="depth: 65.5 m does not fit a 16-bit PNG"):  # 65535 would read as missing
        write_frame(mm, "c", image, far)


def test_write_frame_of_millimetres_says_it_takes_metres(tmp_path):
    """The raw uint16 depth PNG given as metres was "1098.0 m does not fit a 16-bit PNG at 0.001 m per
    unit", which sent one to a coarser depth_scale rather than to metres."""
    src = demo_data_dir()
    raw = cv2.imread(str(src / "cloud_1-depth.png"), cv2.IMREAD_UNCHANGED)
    with pytest.raises(ValueError, match=r"depth: median 977 is not in metres \(at most 50 m expected\); write_frame "
                                         r"takes metres: divide millimetres by 1000"):
        write_frame(tmp_path, "f", cv2.imread(str(src / "cloud_1-rgb.png")), raw, depth_scale=0.1)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- review-io: calibration files, float depth
_KINECT_K = "525 0 319.5 0 525 239.5 0 0 1"


def _opencv_xml(dt: str = "d", data: str = _KINECT_K, extra: str = "") -> str:
    return (f'<?xml version="1.0"?>\n<opencv_storage>\n<intrinsics type_id="opencv-matrix"><rows>3</rows><cols>3</cols>'
            f"<dt>{dt}</dt><data>{data}</data></intrinsics>\n{extra}</opencv_storage>\n")


@pytest.mark.parametrize("text, size", [
    (_opencv_xml(extra="<image_width>1280</image_width>\n<image_height>960</image_height>\n"),
     r"1280x960 \(image_width, image_height\)"),  # what OpenCV's calibration sample writes
    (f"%YAML:1.0\n---\nintrinsics: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [{_KINECT_K.replace(' ', ', ')}]\n"
     "image_size: [1280, 960]\n", r"1280x960 \(image_size\)"),
])
def test_intrinsics_recording_another_image_size_are_refused(tmp_path, text, size):
    """A calibration of 1280x960 frames recording its image size was read for 640x480 frames without a
    word (its principal point (319.5, 239.5) lies on the smaller image too), and every geodesic patch
    was sized with focal lengths twice too long."""
    src = demo_data_dir()
    (tmp_path / "intrinsics.xml").write_text(text)
    np.testing.assert_allclose(read_intrinsics(tmp_path / "intrinsics.xml")[0], [525, 0, 319.5])  # no frames: no check
    with pytest.raises(ValueError, match=rf"intrinsics_path: .*intrinsics.xml records an image size of {size}, but the "
                                         r"frames are 640x480.*fx and cx by 640/1280, fy and cy by 480/960"):
        geofeat.read_frame(src / "cloud_1-rgb.png", src / "cloud_1-depth.png", tmp_path / "intrinsics.xml")
    for name in ("cloud_1-rgb.png", "cloud_1-depth.png"):
        shutil.copy(src / name, tmp_path / name)
    with pytest.raises(ValueError, match=rf"intrinsics.xml records an image size of {size}, but the frames are 640x480"):
        geofeat.read_sequence(tmp_path)
    (tmp_path / "intrinsics.xml").write_text(text.replace("1280", "640").replace("960", "480"))
    assert geofeat.read_sequence(tmp_path).frame(0).K[0, 0] == 525.0  # the frames' own size: read as before


@pytest.mark.parametrize("dt, data, read", [
    ("u", _KINECT_K, r"uint8 \(dt 'u'\), which clips the camera matrix: read as \[255, 0, 255, 0, 255, 240"),
    ("c", _KINECT_K, r"int8 \(dt 'c'\), which clips"),
    ("i", _KINECT_K, r"int32 \(dt 'i'\), which rounds the camera matrix: read as \[525, 0, 320, 0, 525, 240, 0, 0, 1\] "
                     r"\(the file has \[525.0, 0.0, 319.5"),
])
def test_a_camera_matrix_in_an_integer_type_that_changes_it_is_refused(tmp_path, dt, data, read):
    """OpenCV casts an opencv-matrix to its dt: `<dt>u</dt>` (8 bits) saturates fx = 525 to 255 and
    `<dt>i</dt>` rounds cx = 319.5 to 320, and read_intrinsics returned the result without a word."""
    path = tmp_path / "intrinsics.xml"
    path.write_text(_opencv_xml(dt, data))
    with pytest.raises(ValueError, match=rf"intrinsics_path: .*intrinsics.xml: its node 'intrinsics' is stored as {read}.*"
                                         r"<dt>d</dt>"):
        read_intrinsics(path)
    path.write_text(_opencv_xml("i", "525 0 320 0 525 240 0 0 1"))  # whole numbers an int32 holds: nothing lost
    np.testing.assert_array_equal(read_intrinsics(path), [[525, 0, 320], [0, 525, 240], [0, 0, 1]])


def test_a_float_depth_image_in_metres_names_the_python_argument_too(tmp_path):
    """A float TIFF of metres read at the default 0.001 m per unit was refused with "set --depth-scale
    (or depth_scale in geofeat.json)": no help to a read_frame caller, who needs depth_scale=1."""
    src = demo_data_dir()
    cv2.imwrite(str(tmp_path / "depth.tiff"), read_depth(src / "cloud_1-depth.png").astype(np.float32))
    args = (src / "cloud_1-rgb.png", tmp_path / "depth.tiff", src / "intrinsics.xml")
    with pytest.raises(ValueError, match=r"median depth 0.000977 m .*implausible.*--depth-scale on the command line, "
                                         r"depth_scale= in Python.*a float depth image in metres: 1"):
        geofeat.read_frame(*args)
    frame = geofeat.read_frame(*args, depth_scale=1)  # what the message asks for
    assert 0.6 < np.median(frame.depth[frame.depth > 0]) < 1.2


def test_a_depth_png_in_centimetres_read_as_millimetres_is_warned_of_as_centimetres(tmp_path):
    """A depth PNG written in centimetres (the Kinect frame's 0.7-1.1 m as 70-110) read at the default
    millimetres puts the scene at 7-11 cm: inside the plausible range, so only the readers' once-a-file
    DepthUnitsWarning catches it, and it named millimetres alone; it now names the reading that fits."""
    from geofeat.inputs import DepthUnitsWarning

    src = demo_data_dir()
    metres = read_depth(src / "cloud_1-depth.png")
    cv2.imwrite(str(tmp_path / "cloud_1-depth.png"), np.rint(metres * 100).astype(np.uint16))
    for name in ("cloud_1-rgb.png", "intrinsics.xml"):
        shutil.copy(src / name, tmp_path / name)
    reading = r"median depth 0.098 m at depth scale 0.001 m per unit is nearer than usual.*read as centimetres 0.98 m " \
              r"\(depth_scale=0.01\)"
    with pytest.warns(DepthUnitsWarning, match=rf"depth_path: .*cloud_1-depth.png: {reading}"):
        geofeat.read_frame(tmp_path / "cloud_1-rgb.png", tmp_path / "cloud_1-depth.png", tmp_path / "intrinsics.xml")
    with pytest.warns(DepthUnitsWarning, match=rf"sequence .*: {reading}"):
        geofeat.read_sequence(tmp_path)
    frame = geofeat.read_frame(tmp_path / "cloud_1-rgb.png", tmp_path / "cloud_1-depth.png", tmp_path / "intrinsics.xml",
                               depth_scale=0.01)  # what it says
    assert 0.6 < np.median(frame.depth[frame.depth > 0]) < 1.2
