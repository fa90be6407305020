"""The command line: demo, extract, match, and clear errors."""

import re

import numpy as np
import pytest

import geofeat
from geofeat.cli import main
from geofeat.cli.demo import _check_demo_folder
from surfaces import write_rolled_kinect_sequence


@pytest.fixture(scope="module")
def rolled_sequence(tmp_path_factory):
    """The Kinect frame (reference) and the camera rolled by 30 deg, with landmarks, in the public layout."""
    return write_rolled_kinect_sequence(tmp_path_factory.mktemp("rolled"), 30.0)


def test_demo_writes_pictures_and_reports(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--keypoints", "300"]) == 0
    out = capsys.readouterr().out
    assert "51 valid" in out and "geobit" in out and "orb" in out
    assert (tmp_path / "polar_patches.png").stat().st_size > 10_000
    assert (tmp_path / "rolled_pair_matches.png").stat().st_size > 10_000
    # a rerun into the demo's own folder replaces its pictures; a user's picture of the same name elsewhere stays
    _check_demo_folder(tmp_path)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "polar_patches.png").write_bytes(b"my own picture")
    assert main(["demo", "--out", str(mine)]) == 2
    assert "polar_patches.png" in capsys.readouterr().err
    assert (mine / "polar_patches.png").read_bytes() == b"my own picture"


def test_demo_says_first_that_a_first_run_compiles_the_kernels(tmp_path, capsys, monkeypatch):
    """A first `geofeat demo` after installing printed nothing for two minutes while numba compiled its
    kernels (the line saying so came after them): it now says so before any work, and only then."""
    from geofeat.cli import demo
    from geofeat.geodesic.polar import polar_patches
    from geofeat.geodesic.walk import walk_polar
    from geofeat.io import read_demo_frame

    polar_patches(read_demo_frame(), [[320.0, 240.0]])  # the walk compiled and cached, if no test did it before
    assert demo.kernels_compiled()
    monkeypatch.setattr(walk_polar._cache, "_cache_path", str(tmp_path / "empty"))  # numba's cache, as if empty
    assert not demo.kernels_compiled()
    monkeypatch.setattr(demo, "_demo_patches", lambda *a: print("patches"))
    monkeypatch.setattr(demo, "_demo_rolled_pair", lambda *a: None)
    monkeypatch.setattr(demo, "_demo_deformed_pair", lambda *a: None)
    assert main(["demo", "--out", str(tmp_path / "out")]) == 0
    assert capsys.readouterr().out.splitlines()[:2] == [
        "first run: compiling geofeat's numba kernels (about a minute on a 2-core CPU; they are cached for "
        "later runs)", "patches"]
    monkeypatch.undo()
    monkeypatch.setattr(demo, "_demo_patches", lambda *a: print("patches"))
    monkeypatch.setattr(demo, "_demo_rolled_pair", lambda *a: None)
    monkeypatch.setattr(demo, "_demo_deformed_pair", lambda *a: None)
    assert main(["demo", "--out", str(tmp_path / "out")]) == 0
    assert "first run" not in capsys.readouterr().out


def test_demo_match_lines_count_in_words(tmp_path, capsys, monkeypatch):
    """The demo's per-descriptor lines said "1 correct matches ... of 1 keypoints"."""
    from types import SimpleNamespace

    import geofeat.descriptors
    import geofeat.matching
    import geofeat.viz
    import numpy as np

    from geofeat.cli.demo import _demo_match_pair

    monkeypatch.setattr(geofeat.descriptors, "make_descriptor",
                        lambda name, **kw: SimpleNamespace(compute=lambda frame, kps: None))
    matches = iter([np.array([0, -1]), np.array([0, 1])])
    monkeypatch.setattr(geofeat.matching, "match", lambda a, b: SimpleNamespace(matches0=next(matches)))
    monkeypatch.setattr(geofeat.viz, "draw_matches", lambda *a, **kw: np.zeros((4, 4, 3), np.uint8))
    class Keypoints:
        xy = np.array([[1.0, 1.0], [5.0, 5.0]])

        def __len__(self):
            return 2

    kps = Keypoints()
    truth = np.array([[1.0, 1.0], [np.nan, np.nan]])  # one keypoint with a true position
    _demo_match_pair(tmp_path, "pair.png", None, None, kps, kps, truth, ["geobit", "orb"], "kinect")
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "  geobit       1 correct match (< 3 px) of 1 keypoint with a true position (100.0%), " + \
        lines[0].split(", ")[-1]
    assert " 1 correct match (< 3 px)" in lines[1] and "1 keypoint with" in lines[1]


def test_extract_and_match_on_a_sequence(rolled_sequence, tmp_path, capsys):
    features = tmp_path / "f.h5"
    assert main(["extract", str(rolled_sequence), "--out", str(features), "--keypoints", "300"]) == 0
    f = geofeat.load_features(features, name="cloud_roll30")
    assert f.descriptors.shape[1:] == (16, 64) and len(f) <= 300
    # the summary says how many keypoints each frame got (GeoKey may find fewer than --keypoints asks)
    counts = sorted(len(geofeat.load_features(features, name=n)) for n in ("cloud_ref", "cloud_roll30"))
    said = re.search(r"(\d+)(?:-(\d+))? keypoints per frame of --keypoints 300\)", capsys.readouterr().out)
    assert said and [int(said.group(1)), int(said.group(2) or said.group(1))] == counts
    assert main(["match", str(rolled_sequence), "--out", str(tmp_path / "m"), "--keypoints", "300"]) == 0
    m = geofeat.load_matches(tmp_path / "m" / "matches-geobit.h5", name="cloud_ref/cloud_roll30")
    assert (m.matches0 >= 0).sum() > 100
    # the keypoints the matches index are written beside them (hloc's features.h5 + matches.h5): the
    # reference's are GeoKey's on that frame, and every match points at a target keypoint that exists
    f_ref = geofeat.load_features(tmp_path / "m" / "features-geobit.h5", name="cloud_ref")
    f_tgt = geofeat.load_features(tmp_path / "m" / "features-geobit.h5", name="cloud_roll30")
    ref_frame = geofeat.read_sequence(rolled_sequence).frame("cloud_ref")
    assert np.allclose(f_ref.keypoints, geofeat.detect(ref_frame, n=300).xy, atol=1e-4)
    assert len(m.matches0) == len(f_ref) and m.matches0.max() < len(f_tgt)
    total = re.search(r"total: (\d+) matches, (\d+) correct", capsys.readouterr().out)
    assert total and int(total.group(2)) > 50  # ground truth from a thin-plate spline on the csv landmarks
    assert (tmp_path / "m" / "cloud_ref__cloud_roll30__geobit.png").exists()


def test_extract_on_the_gpu_is_refused_clearly_where_it_cannot_run(rolled_sequence, tmp_path, capsys):
    """`extract --device`: a device that is neither the CPU nor CUDA, a descriptor the GPU path does not
    compute (the default GeoBit, ORB, GeoPatch from an .onnx file) and, on a machine without a CUDA
    GPU, CUDA itself are one-line usage errors naming the flag, before any frame is read."""
    import torch

    seq, out = str(rolled_sequence), str(tmp_path / "f.h5")
    onnx = tmp_path / "x.onnx"
    onnx.write_bytes(b"")  # the option's own check wants the file to exist
    cases = [(["--device", "tpu"], "--device: expected cpu, cuda or cuda:N"),
             (["--device", "cuda"], "GeoPatch with torch weights only"),
             (["--device", "cuda", "--descriptor", "orb"], "not orb"),
             (["--device", "cuda", "--descriptor", f"geopatch={onnx}"], "x.onnx")]
    if not torch.cuda.is_available():
        cases.append((["--device", "cuda", "--descriptor", "geopatch"], "--device cuda: "))
    for extra, message in cases:
        assert main(["extract", seq, "--out", out, "--keypoints", "50", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith("geofeat extract: error: ") and message in err, (extra, err)
    assert not (tmp_path / "f.h5").exists()


def test_match_on_the_gpu_is_refused_clearly_where_it_cannot_run(rolled_sequence, tmp_path, capsys):
    """`match` had no --device (extract has): its checks are extract's, one-line usage errors naming the
    flag before any frame is read, for a device that is neither the CPU nor CUDA, a descriptor the GPU
    path does not compute and, on a machine without a CUDA GPU, CUDA itself."""
    import torch

    cases = [(["--device", "tpu"], "--device: expected cpu, cuda or cuda:N"),
             (["--device", "cuda"], "GeoPatch with torch weights only"),
             (["--device", "cuda", "--descriptor", "orb"], "not orb")]
    if not torch.cuda.is_available():
        cases.append((["--device", "cuda", "--descriptor", "geopatch"], "--device cuda: "))
    for extra, message in cases:
        assert main(["match", str(rolled_sequence), "--out", str(tmp_path / "m"), "--keypoints", "50", *extra]) == 2
        err = capsys.readouterr().err
        assert err.startswith("geofeat match: error: ") and message in err, (extra, err)
    assert not (tmp_path / "m").exists()


def test_match_device_reaches_the_description_and_the_matching(rolled_sequence, tmp_path, monkeypatch):
    """`match --device cuda:0` describes GeoPatch on the GPU path (`compute_cuda`, torch backend on that
    device) and matches there (`geofeat.match(..., device=)`), as `extract --device` describes; without
    it, both stay on the CPU. (No GPU here: the GPU calls are stood in for by the CPU's.)"""
    from types import SimpleNamespace

    import geofeat.descriptors
    import geofeat.gpu
    import geofeat.matching

    made, matched = [], []
    make_descriptor, match = geofeat.descriptors.make_descriptor, geofeat.matching.match

    def recording_make(name, **kwargs):
        made.append({k: kwargs[k] for k in ("device", "backend") if k in kwargs})
        cpu = make_descriptor(name, **{k: v for k, v in kwargs.items() if k not in ("device", "backend")})
        cpu.compute_cuda = lambda frame, kps: SimpleNamespace(to_host=lambda: cpu.compute(frame, kps))
        return cpu

    def recording_match(f0, f1, *args, device=None, **kwargs):
        matched.append(device)
        return match(f0, f1, *args, **kwargs)

    monkeypatch.setattr(geofeat.gpu, "require_cuda", lambda device="cuda": None)  # a usable GPU, as far as asked
    monkeypatch.setattr(geofeat.descriptors, "make_descriptor", recording_make)
    monkeypatch.setattr(geofeat.matching, "match", recording_match)
    args = ["match", str(rolled_sequence), "--descriptor", "geopatch", "--keypoints", "50"]
    assert main([*args, "--out", str(tmp_path / "gpu"), "--device", "cuda:0"]) == 0
    assert made == [{"device": "cuda:0", "backend": "torch"}] and matched == ["cuda:0"]
    made.clear(), matched.clear()
    assert main([*args, "--out", str(tmp_path / "cpu")]) == 0
    assert made == [{}] and matched == [None]


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="no CUDA GPU")
def test_extract_on_the_gpu_equals_the_torch_backend_on_the_cpu(rolled_sequence, tmp_path, monkeypatch):
    """`extract --device cuda` writes the GPU path's GeoPatch features: the same keypoints and valid
    flags as the CPU run, descriptors close to the CPU's torch backend: the median within 2e-4, 99 %
    within 5e-4, all within 1e-2 (rays that graze a mesh vertex; `test_gpu.test_gpu_path_equals_cpu_path`)."""
    import numpy as np

    monkeypatch.setenv("GEOFEAT_GEOPATCH_BACKEND", "torch")
    args = ["extract", str(rolled_sequence), "--descriptor", "geopatch", "--keypoints", "300"]
    assert main([*args, "--out", str(tmp_path / "cpu.npz")]) == 0
    assert main([*args, "--out", str(tmp_path / "gpu.npz"), "--device", "cuda"]) == 0
    for name in ("cloud_ref", "cloud_roll30"):
        a, b = (geofeat.load_features(tmp_path / f"{run}-{name}.npz") for run in ("cpu", "gpu"))
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
        np.testing.assert_array_equal(a.valid, b.valid)
        err = np.abs(a.descriptors - b.descriptors).max(1)
        print(f"{name}: descriptor differences, median {np.median(err):.1e}, 99 % {np.quantile(err, 0.99):.1e}, "
              f"largest {err.max():.1e}")
        # the mesh smoothed on the GPU in float32 moves samples by thousandths of a pixel (measured on
        # an H100, these two frames: median 8.8e-5, 99 % 1.4e-4, largest 1.7e-4)
        assert np.median(err) < 2e-4 and np.quantile(err, 0.99) < 5e-4 and err.max() < 1e-2


def test_match_prints_the_matches_without_ground_truth_apart_from_the_wrong_ones(rolled_sequence, tmp_path, capsys,
                                                                                 monkeypatch):
    """`match` printed "N matches, C correct", so matches whose target keypoint has no ground truth
    (occluded, off the surface, outside the landmarks' hull) read as wrong. With the ground truth of
    the left half of the target only, the right half's matches are counted as not judged."""
    import numpy as np

    from geofeat.groundtruth.sources import GroundTruth

    known_map = GroundTruth.map

    def left_half_only(self, target, xy):
        xy_ref, valid = known_map(self, target, xy)
        right = np.asarray(xy)[:, 0] >= 320  # the 640 px wide Kinect frame's right half
        xy_ref = xy_ref.copy()
        xy_ref[right] = np.nan
        return xy_ref, valid & ~right

    monkeypatch.setattr(GroundTruth, "map", left_half_only)
    assert main(["match", str(rolled_sequence), "--out", str(tmp_path / "m"), "--keypoints", "300"]) == 0
    out = capsys.readouterr().out
    pair = re.search(r"cloud_ref -> cloud_roll30: (\d+) matches, (\d+) correct, (\d+) not judged \(no ground truth\)", out)
    total = re.search(r"total: (\d+) matches, (\d+) correct, (\d+) not judged \(no ground truth\)", out)
    assert pair and total and pair.groups() == total.groups()
    n, correct, unjudged = map(int, total.groups())
    assert 0 < unjudged < n and correct + unjudged <= n and correct > 20


def test_errors_are_one_line_and_exit_2(tmp_path, capsys):
    assert main(["extract", str(tmp_path / "missing"), "--out", str(tmp_path / "f.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a directory" in err[0]
    with pytest.raises(SystemExit):
        main(["extract", str(tmp_path), "--descriptor", "nope", "--out", "x"])


@pytest.mark.parametrize("command", ["extract", "match", "bench", "retrieval", "track"])
def test_keypoints_must_be_positive(tmp_path, capsys, command):
    """--keypoints 0 is a usage error naming the option, not every frame skipped or the dataset blamed."""
    with pytest.raises(SystemExit) as stop:
        main([command, str(tmp_path), "--keypoints", "0", "--out", str(tmp_path / "out")])
    assert stop.value.code == 2 and "--keypoints: expected a positive number" in capsys.readouterr().err


def test_demo_pictures_replace_a_link_not_its_target_and_leave_no_partial_file(tmp_path, monkeypatch):
    """A demo picture listed in the folder's manifest but now a link to a user's picture: the demo
    replaces the link, never writes into the linked file; a failed write leaves no temporary file."""
    import numpy as np

    from geofeat.outputs import write_picture

    mine = tmp_path / "paper-figure.png"
    mine.write_bytes(b"my figure")
    out = tmp_path / "demo"
    out.mkdir()
    (out / "polar_patches.png").symlink_to(mine)
    write_picture(out / "polar_patches.png", np.zeros((8, 8, 3), np.uint8))
    assert mine.read_bytes() == b"my figure"
    assert not (out / "polar_patches.png").is_symlink() and (out / "polar_patches.png").stat().st_size > 0
    import cv2

    def half_written(path, image):
        open(path, "wb").write(b"\x89PNG")
        return False

    monkeypatch.setattr(cv2, "imwrite", half_written)
    with pytest.raises(OSError, match="cannot write"):
        write_picture(out / "rolled_pair_matches.png", np.zeros((8, 8, 3), np.uint8))
    assert sorted(p.name for p in out.iterdir()) == ["polar_patches.png"]


def test_demo_refuses_a_user_folder_named_simulated_cloth_before_any_work(tmp_path):
    (tmp_path / "simulated_cloth").mkdir()
    (tmp_path / "simulated_cloth" / "my-notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="simulated_cloth.*did not write"):
        _check_demo_folder(tmp_path)


@pytest.mark.parametrize("argv, flag", [
    (["extract", "SEQ", "--keypoints", "-3"], "--keypoints"),
    (["extract", "SEQ", "--radius", "0"], "--radius"),
    (["match", "SEQ", "--depth-scale", "-0.001"], "--depth-scale"),
    (["bench", "SEQ", "--radius", "0"], "--radius"),
    (["bench", "SEQ", "--workers", "0"], "--workers"),
    (["retrieval", "SEQ", "--words", "1"], "--words"),
    (["retrieval", "SEQ", "--rerank", "-1"], "--rerank"),
    (["retrieval", "SEQ", "--samples", "0"], "--samples"),
    (["track", "SEQ", "--threshold", "0"], "--threshold"),
    (["track", "SEQ", "--radius", "nan"], "--radius"),
    (["simulate", "OUT", "--frames", "0"], "--frames"),
    (["simulate", "OUT", "--width", "10"], "--width"),
    (["simulate", "OUT", "--seed", "-1"], "--seed"),
    # seeds past what the random generators take failed after the work, unnamed ("Seed must be between 0
    # and 2**32 - 1", "Overflow when unpacking long long"; train after writing its patch cache)
    (["retrieval", "SEQ", "--seed", str(2**32)], "--seed"),
    (["train", "--data", "SEQ", "--seed", str(2**64)], "--seed"),
    (["train-detector", "--data", "SEQ", "--val", "SEQ", "--seed", str(2**64)], "--seed"),
    (["simulate", "OUT", "--fov", "10"], "--fov"),
    (["extract", "SEQ", "--depth-profile", "lidar"], "--depth-profile"),
])
def test_bad_option_values_are_usage_errors_naming_the_flag(rolled_sequence, tmp_path, capsys, argv, flag):
    """A bad value was reported under the Python parameter behind it ("words: expected ...", "n: ...")
    or, for bench --radius 0, only after every sequence had failed; now argparse refuses it by flag
    (exit 2) before anything is read or written."""
    out = tmp_path / "out"
    argv = [str(rolled_sequence) if a == "SEQ" else str(out) if a == "OUT" else a for a in argv]
    if argv[0] != "simulate":
        argv += ["--out", str(out)]
    with pytest.raises(SystemExit) as stop:
        main(argv)
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert stop.value.code == 2 and last.startswith(f"geofeat {argv[0]}: error: argument {flag}: "), last
    assert not out.exists()


def test_detector_and_descriptor_names_in_any_case_are_recorded_lower_case(rolled_sequence, tmp_path):
    """`--detector SIFT` was refused; names are recorded in their canonical lower case."""
    import csv
    import json

    out = tmp_path / "b"
    assert main(["bench", str(rolled_sequence), "--descriptors", "ORB,Sift", "--detector", "SIFT",
                 "--keypoints", "100", "--out", str(out)]) == 0
    with open(out / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert {(r["descriptor"], r["detector"]) for r in rows} == {("orb", "sift"), ("sift", "sift")}
    config = json.loads((out / "config.json").read_text())
    assert config["descriptors"] == ["orb", "sift"] and config["detector"] == "sift"
    assert "| sequences | orb | sift |" in (out / "table.md").read_text()
    # a rerun naming them in another case is the same run: nothing is redone
    assert main(["bench", str(rolled_sequence), "--descriptors", "orb,SIFT", "--detector", "Sift",
                 "--keypoints", "100", "--out", str(out)]) == 0
    with open(out / "results.csv", newline="") as fh:
        assert list(csv.DictReader(fh)) == rows


def test_demo_rolled_pair_counts_only_keypoints_that_stay_in_the_frame(tmp_path, monkeypatch):
    """The rolled pair's "correct matches of N keypoints with a true position" counted every reference
    keypoint, also those the roll carries out of the image (137 of 1000 at 60 deg), which no descriptor
    can match: the rate printed beside it was lower than the descriptors' for the keypoints they could find."""
    import numpy as np

    from geofeat.cli import demo
    from geofeat.frame import roll_camera
    from geofeat.io import read_demo_frame
    from geofeat.keypoints import detect

    seen = {}
    monkeypatch.setattr(demo, "_demo_match_pair", lambda out, name, f0, f1, k0, k1, truth, *a: seen.update(k0=k0, truth=truth))
    demo._demo_rolled_pair(tmp_path, 60.0, 500, "kinect")
    frame = read_demo_frame()
    _, A = roll_camera(frame, 60.0)
    k0 = detect(frame, 500, detector="sift")
    where = k0.xy @ A[:, :2].T + A[:, 2]
    H, W = frame.shape
    inside = (where >= 0).all(axis=1) & (where[:, 0] <= W - 1) & (where[:, 1] <= H - 1)
    assert 0 < inside.sum() < len(k0)
    known = np.isfinite(seen["truth"]).all(axis=1)
    np.testing.assert_array_equal(known, inside)
    np.testing.assert_allclose(seen["truth"][known], where[inside])


def test_an_unknown_option_is_reported_with_the_command_usage(tmp_path, capsys):
    """`geofeat extract SEQ -n 128` printed the top-level usage (the list of commands) and
    "geofeat: error: unrecognized arguments: -n 128", not the options extract does take."""
    with pytest.raises(SystemExit) as stop:
        main(["extract", str(tmp_path), "--out", str(tmp_path / "f.h5"), "-n", "128"])
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert err.startswith("usage: geofeat extract ") and "--keypoints KEYPOINTS" in err
    assert err.strip().splitlines()[-1] == "geofeat extract: error: unrecognized arguments: -n 128"


def test_every_option_of_every_command_has_help():
    """`geofeat bench --help` listed `--protocol {detect,landmarks}` with no word on what either does."""
    import argparse

    from geofeat.cli import build_parser

    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    bare = [f"{name} {a.option_strings or a.dest}" for name, sub in commands.choices.items() for a in sub._actions
            if not a.help]
    assert not bare


def test_demo_slope_noise_line_gives_its_unit_and_threshold(tmp_path, capsys):
    """The demo printed "auto: measured slope noise 0.52", a bare number: neither its unit nor what it was compared with."""
    from geofeat.cli.demo import _demo_patches

    _demo_patches(tmp_path, 0.075, "auto")
    line = next(l for l in capsys.readouterr().out.splitlines() if l.startswith("depth profile:"))
    assert re.search(r"slope noise 0\.\d\d pixel footprints, above the kinect profile's threshold 0\.3\)", line), line


def test_match_fails_when_a_match_picture_cannot_be_written(rolled_sequence, tmp_path, monkeypatch, capsys):
    """OpenCV's imwrite returns False instead of raising (a file name over the system's limit, a full
    disk): `match` said "one match picture per pair" with the picture missing."""
    import cv2

    monkeypatch.setattr(cv2, "imwrite", lambda *args, **kwargs: False)
    assert main(["match", str(rolled_sequence), "--out", str(tmp_path / "m"), "--keypoints", "300"]) != 0
    captured = capsys.readouterr()
    assert "cannot write the picture" in captured.err and "match picture" not in captured.out
    assert not (tmp_path / "m").exists()  # nothing half written


@pytest.fixture(scope="module")
def small_simulated(tmp_path_factory):
    """A simulated sequence of two 160 x 120 frames with exact ground truth (a few seconds)."""
    from geofeat.sim import simulate_sequence

    return simulate_sequence(tmp_path_factory.mktemp("small") / "cloth-rotate", scenario="rotate", n_frames=2, seed=5,
                             width=160, height=120, progress=False)


@pytest.mark.parametrize("damage", ["truncated npz", "json not an object", "json without spacing", "json corrupt"])
def test_match_names_a_damaged_simulator_ground_truth_file_in_one_line(small_simulated, tmp_path, capsys, damage):
    """A truncated <frame>-gt.npz was a BadZipFile traceback in `geofeat match`; a groundtruth.json
    holding a list a TypeError traceback, one without spacing_m a KeyError traceback, a corrupt one a
    bare JSON error naming no file."""
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(small_simulated, seq)
    if damage == "truncated npz":
        (seq / "frame-001-gt.npz").write_bytes((seq / "frame-001-gt.npz").read_bytes()[:300])
        named = "frame-001-gt.npz"
    else:
        (seq / "groundtruth.json").write_text({"json not an object": "[1]", "json without spacing": '{"frames": []}',
                                               "json corrupt": "{"}[damage])
        named = "groundtruth.json"
    assert main(["match", str(seq), "--descriptor", "sift", "--keypoints", "64", "--out", str(tmp_path / "m")]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "%|" not in line]  # no progress bars
    assert len(err) == 1 and err[0].startswith("geofeat match: error: ") and named in err[0], err
    assert not (tmp_path / "m").exists()


def test_bench_timing_is_taken_on_a_sequence_that_did_not_fail(small_simulated, tmp_path, capsys):
    """`bench --timing` timed the first sequence found; when that one had failed (an unreadable reference
    frame), the run ended with its read error, exit 2, after the results of the others were written:
    no timing.md and no FAILED line, where the other sequences' results make it exit 1."""
    import shutil

    data = tmp_path / "data"
    shutil.copytree(small_simulated, data / "a-bad")
    shutil.copytree(small_simulated, data / "b-good")
    (data / "a-bad" / "frame-000-master-rgb.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    out = tmp_path / "bench"
    assert main(["bench", str(data), "--descriptors", "sift", "--keypoints", "64", "--out", str(out), "--timing"]) == 1
    assert "FAILED sequences: a-bad" in capsys.readouterr().out
    assert (out / "timing.md").is_file()


def test_bench_reads_the_features_extract_wrote_for_an_upper_case_npz_name(small_simulated, tmp_path, capsys):
    """`extract --out F.NPZ` writes F-<frame>.npz (the suffix in lower case), but `bench --features x=F.NPZ`
    looked for F-<frame>.NPZ and refused the path: "does not exist (nor any F-<frame>.npz beside it...)"."""
    out = tmp_path / "F.NPZ"
    assert main(["extract", str(small_simulated), "--descriptor", "sift", "--keypoints", "64", "--out", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [".geofeat-manifest.json",  # extract's files, recorded
                                                          "F-frame-000-master.npz", "F-frame-001.npz",
                                                          "F.source.json"]  # the sequence they are features of
    assert main(["bench", str(small_simulated), "--descriptors", "sift", "--keypoints", "64",
                 "--features", f"x={out}", "--out", str(tmp_path / "bench")]) == 0
    header = (tmp_path / "bench" / "table.md").read_text().splitlines()[0]
    assert header.replace(" ", "").startswith("|sequences|") and "| x |" in header


def test_bench_refuses_the_features_extract_wrote_of_another_sequence(small_simulated, tmp_path, capsys):
    """Simulated sequences share their frame names (frame-000-master, frame-001, ...), so `bench
    --features x=F.npz` on one sequence read the F-<frame>.npz files that extract wrote of another and
    scored them without a word. The record extract writes beside them (F.source.json) now tells."""
    import shutil

    import cv2

    other = shutil.copytree(small_simulated, tmp_path / "data" / small_simulated.name)
    ref = other / "frame-000-master-rgb.png"
    cv2.imwrite(str(ref), cv2.flip(cv2.imread(str(ref)), 1))  # another sequence of the same name and frames
    out = tmp_path / "feats" / "F.npz"
    assert main(["extract", str(small_simulated), "--descriptor", "sift", "--keypoints", "64", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["bench", str(other), "--descriptors", "sift", "--keypoints", "64", "--features", f"x={out}",
                 "--out", str(tmp_path / "bench")]) == 2
    err = capsys.readouterr().err
    assert "F.source.json says the F-<frame>.npz files there are features of" in err and str(other) in err
    assert not (tmp_path / "bench").exists()
    copy = shutil.copytree(small_simulated, tmp_path / "copy" / small_simulated.name)  # the same sequence elsewhere
    assert main(["bench", str(copy), "--descriptors", "sift", "--keypoints", "64", "--features", f"x={out}",
                 "--out", str(tmp_path / "bench2")]) == 0


def test_simulate_reruns_with_overwrite_over_its_own_contact_sheet_in_the_folder(tmp_path, capsys):
    """`simulate S --contact-sheet S/sheet.png` left the sheet out of the folder's manifest, so the same
    command with --overwrite refused S: "holds files geofeat did not write (sheet.png)"."""
    argv = ["simulate", str(tmp_path / "s"), "--frames", "2", "--width", "64", "--height", "48", "--texture",
            "procedural", "--no-progress", "--contact-sheet", str(tmp_path / "s" / "sheet.png")]
    assert main(argv) == 0
    assert main(argv + ["--overwrite"]) == 0, capsys.readouterr().err
    assert (tmp_path / "s" / "sheet.png").is_file()


def test_bench_reruns_with_other_settings_into_a_folder_that_holds_no_result(small_simulated, tmp_path, capsys):
    """A bench run whose every sequence failed leaves results.csv with its header only; a rerun with other
    settings was refused: "holds results made with other settings ...; use --overwrite"."""
    import shutil

    seq = tmp_path / "cloth"
    shutil.copytree(small_simulated, seq)
    frame = (seq / "frame-001-rgb.png").read_bytes()
    (seq / "frame-001-rgb.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    out = tmp_path / "bench"
    assert main(["bench", str(seq), "--descriptors", "sift", "--keypoints", "64", "--out", str(out)]) == 2
    (seq / "frame-001-rgb.png").write_bytes(frame)
    capsys.readouterr()
    assert main(["bench", str(seq), "--descriptors", "sift", "--keypoints", "32", "--out", str(out)]) == 0, \
        capsys.readouterr().err
    assert (out / "table.md").is_file()


def test_demo_radius_reaches_the_descriptors_of_both_pairs(small_simulated, tmp_path, monkeypatch):
    """`geofeat demo --radius R` drew the patches at R but matched both pairs with GeoBit and GeoPatch
    at the default 0.075 m: the option was silently ignored for every figure the demo prints."""
    from types import SimpleNamespace

    import numpy as np

    import geofeat.descriptors
    import geofeat.matching
    import geofeat.sim
    import geofeat.viz
    from geofeat.cli import demo

    radii = {}

    def make_descriptor(name, radius=None, **kw):  # the descriptors' work is not what is tested
        radii.setdefault(name, []).append(radius)
        return SimpleNamespace(compute=lambda frame, kps: kps)

    monkeypatch.setattr(geofeat.descriptors, "make_descriptor", make_descriptor)
    monkeypatch.setattr(geofeat.matching, "match", lambda a, b: SimpleNamespace(matches0=np.full(len(a), -1)))
    monkeypatch.setattr(geofeat.viz, "draw_matches", lambda *a, **kw: np.zeros((4, 4, 3), np.uint8))
    monkeypatch.setattr(demo, "_demo_patches", lambda *a, **kw: None)
    monkeypatch.setattr(geofeat.sim, "simulate_sequence", lambda *a, **kw: small_simulated)  # a small cloth pair
    assert main(["demo", "--out", str(tmp_path / "demo"), "--radius", "0.05", "--keypoints", "100"]) == 0
    assert radii["geobit"] == [0.05, 0.05] and radii["geopatch"] == [0.05]
