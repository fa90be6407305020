"""Tests of `geofeat groundtruth`: the spline layout, robust landmarks, photometric refinement against
exact ground truth (an analytic warp, and the cloth simulator), the bench reading the files, bad input."""

from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from geofeat.groundtruth.sources import GroundTruth
from geofeat.groundtruth.sources import load_authors_spline
from geofeat.tps import ThinPlateSpline, authors_tps
from geofeat.cli import main
from geofeat.groundtruth import GroundTruthConfig, RefineConfig, generate_ground_truth, robust_landmark_tps
from geofeat.groundtruth.validate import keep_landmarks, mapping_errors
from geofeat.io import read_sequence, write_frame, write_intrinsics, write_landmarks
from geofeat.sim import simulate_sequence
from geofeat.sim.textures import packaged_texture_dir

W, H = 160, 120
FAST = RefineConfig(iterations=(8, 15, 25))


def _displacement(p: np.ndarray) -> np.ndarray:
    """Smooth reference -> target displacement (pixels) of the analytic test warp."""
    x, y = p[:, 0], p[:, 1]
    return np.stack([3.0 + 4.0 * np.sin(2 * np.pi * y / 110), -2.0 + 3.5 * np.sin(2 * np.pi * x / 130)], axis=1)


def _forward(p: np.ndarray) -> np.ndarray:
    return p + _displacement(p)


def _inverse(q: np.ndarray) -> np.ndarray:
    """Target -> reference by fixed-point iteration (the displacement's gradient is well below 1)."""
    p = q.copy()
    for _ in range(60):
        p = q - _displacement(p)
    return p


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 1, (H, W)).astype(np.float32), (0, 0), 1.5)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def _write_pair(folder: Path, landmarks: np.ndarray, target_landmarks: np.ndarray | None = None) -> Path:
    """A reference and one target frame warped by the analytic map; landmarks at the given reference pixels."""
    folder.mkdir(parents=True, exist_ok=True)
    ref = _texture(0)
    gx, gy = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    src = _inverse(np.stack([gx.ravel(), gy.ravel()], 1)).reshape(H, W, 2).astype(np.float32)
    tgt = cv2.remap(ref, src[..., 0], src[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    depth = np.full((H, W), 1.0)
    write_intrinsics(folder / "intrinsics.xml", np.array([[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]]))
    write_frame(folder, "frame-000-master", ref, depth)
    write_frame(folder, "frame-001", tgt, depth)
    ids = np.arange(len(landmarks))
    tl = _forward(landmarks) if target_landmarks is None else target_landmarks
    write_landmarks(folder / "frame-000-master.csv", ids, landmarks, np.ones(len(ids), bool))
    write_landmarks(folder / "frame-001.csv", ids, tl, np.ones(len(ids), bool))
    return folder


def _grid_landmarks(n: int = 5) -> np.ndarray:
    gx, gy = np.meshgrid(np.linspace(35, W - 35, n), np.linspace(30, H - 30, n))
    return np.stack([gx.ravel(), gy.ravel()], 1)


def test_tps_is_the_authors_warp_and_interpolates():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 300, (30, 2))
    dst = src + rng.normal(0, 4, (30, 2))
    tps = authors_tps(src, dst, (320, 240))
    theta, ctrl = tps.authors_arrays()
    assert theta.shape == (1, 33, 2) and ctrl.shape == (30, 2)
    q = rng.uniform(0, 300, (50, 2))
    np.testing.assert_allclose(ThinPlateSpline.from_authors_arrays(theta, ctrl, (320, 240))(q), tps(q), atol=1e-3)
    np.testing.assert_allclose(tps(src), dst, atol=1e-6)


def test_robust_spline_rejects_mislabelled_landmarks():
    src = _grid_landmarks(6)
    dst = _forward(src)
    dst[[4, 20]] += [[25.0, 0.0], [0.0, -30.0]]  # two clicks on the wrong place
    fit = robust_landmark_tps(src, dst, (W, H))
    assert set(np.flatnonzero(~fit.inliers)) == {4, 20}
    clean = robust_landmark_tps(src, _forward(src), (W, H))
    assert clean.inliers.all()


def test_refinement_recovers_an_analytic_warp(tmp_path):
    """Few landmarks leave the spline off by pixels between them; refinement brings it well below 1 px."""
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    seq = read_sequence(folder)
    q = np.stack(np.meshgrid(np.arange(30, W - 30, 4.0), np.arange(25, H - 25, 4.0)), -1).reshape(-1, 2)
    truth = _inverse(q)
    errors = {}
    for refine in (False, True):
        out = tmp_path / f"gt{int(refine)}"
        reports = generate_ground_truth(seq, out, GroundTruthConfig(refine=refine, spacing=12, refine_config=FAST),
                                        progress=False)
        assert [r.status for r in reports] == ["ok"]
        mapped = load_authors_spline(out, "frame-001", (W, H))(q)
        errors[refine] = np.linalg.norm(mapped - truth, axis=1)
    assert np.percentile(errors[False], 90) > 1.0  # the landmark spline alone is visibly off
    assert np.median(errors[True]) < 0.3
    assert np.percentile(errors[True], 90) < 0.5 * np.percentile(errors[False], 90)
    assert reports[0].ssim_after > reports[0].ssim_before


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    root = tmp_path_factory.mktemp("gtsim")
    # one target frame 100 simulation steps after the reference (a strong deformation), 320x240, 15 landmarks
    full = simulate_sequence(root / "full", "deform", n_frames=2, seed=3, width=320, height=240, steps_per_frame=100,
                             texture=packaged_texture_dir() / "budgie_the-spices-of-life.jpg", progress=False)
    seq = read_sequence(keep_landmarks(full, root / "k15", 15, seed=0))
    out = {}
    for refine in (False, True):
        out[refine] = root / f"gt{int(refine)}" / seq.name
        generate_ground_truth(seq, out[refine], GroundTruthConfig(refine=refine, refine_config=FAST), progress=False)
    return seq, out


def test_refined_ground_truth_beats_the_landmark_spline_on_the_simulator(simulated):
    """The issue's acceptance check, small: few landmarks, exact simulator correspondences."""
    seq, out = simulated
    for target in seq.targets:
        lm = mapping_errors(seq, out[False], target)
        ref = mapping_errors(seq, out[True], target)
        assert np.median(ref.inside) <= 1.0
        assert np.percentile(ref.inside, 90) <= 0.7 * np.percentile(lm.inside, 90)
        assert np.median(ref.outside) <= np.median(lm.outside) + 0.1
        assert np.percentile(ref.outside, 90) <= np.percentile(lm.outside, 90) + 0.1


def test_bench_reads_the_generated_files(simulated):
    seq, out = simulated
    truth = GroundTruth(seq, str(out[True].parent))
    assert truth.tps is not None
    target = seq.targets[-1]
    frame = seq.frame(target)
    rng = np.random.default_rng(0)
    xy = rng.uniform([0, 0], [frame.shape[1] - 1, frame.shape[0] - 1], (3000, 2))
    mapped, kept = truth.map(target, xy)
    exact, visible = seq.correspondences(target, seq.reference, xy)
    assert np.isfinite(mapped[kept]).all() and np.isnan(mapped[~kept]).all()
    assert kept.sum() > 0.5 * visible.sum()  # most of the visible cloth keeps a ground truth
    assert visible[kept].mean() > 0.95  # and almost nothing off the cloth or hidden does
    err = np.linalg.norm(mapped[kept & visible] - exact[kept & visible], axis=1)
    assert np.median(err) < 0.5
    ref_mask = cv2.imread(str(out[True] / f"{seq.reference}_objmask.png"), cv2.IMREAD_GRAYSCALE)
    assert ref_mask is not None and (ref_mask > 0).any()


def test_resume_keeps_the_sequences_an_interrupted_run_finished(tmp_path, capsys):
    """An interrupted run over several sequences could not be continued: a plain rerun was refused
    (the first sequence's folder exists) and --overwrite made every sequence again."""
    for name in ("a", "b"):
        _write_pair(tmp_path / "seqs" / name, _grid_landmarks(3))
    out = tmp_path / "out"
    args = ["groundtruth", str(tmp_path / "seqs"), "--out", str(out), "--no-refine", "--no-progress"]
    assert main(args) == 0
    kept = (out / "a" / "report.json").stat().st_mtime_ns
    shutil.rmtree(out / "b")  # as if the run had been stopped during b
    capsys.readouterr()
    assert main(args) == 2
    assert "or pass --resume" in capsys.readouterr().err
    assert main(args + ["--resume"]) == 0
    assert "kept 1 sequence finished by an earlier run: a" in capsys.readouterr().out
    assert (out / "a" / "report.json").stat().st_mtime_ns == kept and (out / "b" / "report.json").is_file()
    # what --resume cannot keep is refused by name, before any work
    assert main(args + ["--resume", "--margin", "12"]) == 2
    assert "other settings (margin_px)" in capsys.readouterr().err
    cv2.imwrite(str(tmp_path / "seqs" / "a" / "frame-001-rgb.png"), np.zeros((H, W, 3), np.uint8))
    assert main(args + ["--resume"]) == 2
    assert "frames or landmarks changed since" in capsys.readouterr().err


def test_groundtruth_reads_the_depth_at_the_depth_scale_it_is_given(tmp_path, capsys):
    """`groundtruth` had no --depth-scale, though its depth-units warning advised one: 0.1 mm depth PNGs
    without a geofeat.json were read as millimetres, 10x too far, and the object mask (depths within
    --depth-margin metres of the landmarks') cut off the cloth's near and far edges. A --resume at
    another depth scale is refused, as one with other settings is."""
    from geofeat.inputs import DepthUnitsWarning

    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    ramp = np.broadcast_to(1.0 + 0.1 * np.arange(W) / W, (H, W))  # a cloth sloping away, 1.0-1.1 m
    for name in ("frame-000-master", "frame-001"):
        cv2.imwrite(str(folder / f"{name}-depth.png"), np.rint(ramp / 1e-4).astype(np.uint16))
    args = ["groundtruth", str(folder), "--no-refine", "--no-progress", "--out"]
    with pytest.warns(DepthUnitsWarning, match=r"median depth 10.\d m .*farther than usual"):
        assert main(args + [str(tmp_path / "in-mm")]) == 0
    mask = tmp_path / "in-mm" / "seq" / "frame-000-master_objmask.png"
    assert not (cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE) > 0).all()
    out = tmp_path / "out"
    args += [str(out)]
    assert main(args + ["--depth-scale", "0.0001"]) == 0
    mask = out / "seq" / "frame-000-master_objmask.png"  # the margins reach past every pixel: all of it is the object
    assert (cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE) > 0).all()
    assert json.loads((out / "seq" / "report.json").read_text())["depth_scale"] == 0.0001
    capsys.readouterr()
    assert main(args + ["--depth-scale", "0.0002", "--resume"]) == 2
    assert "another depth scale (0.0001 m per unit there, 0.0002 now)" in capsys.readouterr().err
    assert main(args + ["--depth-scale", "0.0001", "--resume"]) == 0
    assert "kept 1 sequence finished by an earlier run: seq" in capsys.readouterr().out


def test_resume_does_not_keep_a_folder_whose_files_a_killed_run_had_not_all_moved_in(tmp_path, capsys):
    """`replace_folder` moves the files in one by one, in name order, and report.json sorts before the
    files of a frame named after "report" ("view-001_theta.npy"): a run killed (SIGKILL) in between left
    report.json, listed in the manifest, and --resume kept the folder without the frame's TPS files."""
    _write_pair(tmp_path / "seq", _grid_landmarks(3))
    out = tmp_path / "out"
    args = ["groundtruth", str(tmp_path / "seq"), "--out", str(out), "--no-refine", "--no-progress"]
    assert main(args) == 0
    for path in (out / "seq").glob("frame-001_*"):  # what the kill left in the temporary folder
        path.unlink()
    capsys.readouterr()
    assert main(args + ["--resume"]) == 2
    assert "kept" not in capsys.readouterr().out
    assert main(args + ["--overwrite"]) == 0 and (out / "seq" / "frame-001_theta.npy").is_file()


def test_cli_writes_layout_and_report(tmp_path, capsys):
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-refine", "--no-progress"]) == 0
    out = tmp_path / "out" / "seq"
    for name in ["frame-000-master_objmask.png", "frame-001_objmask.png", "frame-001_theta.npy",
                 "frame-001_ctrlpts.npy", "frame-001_SSIM.png", "frame-001_overlay.png", "report.csv", "report.json"]:
        assert (out / name).is_file(), name
    assert np.load(out / "frame-001_theta.npy").shape == (1, 9 + 3, 2)
    printed = capsys.readouterr().out
    assert "seq: 1 of 1 frame, landmark residual" in printed  # it said "1/1 frames"
    # the in-sample residual was printed alone, as if it were the ground truth's accuracy
    loo = float(re.search(r"leave-one-out ([0-9.]+) px", printed).group(1))
    report = json.loads((out / "report.json").read_text())
    frames = report["frames"] if isinstance(report, dict) else report
    assert loo == pytest.approx(frames[0]["loo_median_px"], abs=0.006)


def test_too_few_landmarks_mark_the_frame_failed(tmp_path, capsys):
    lms = _grid_landmarks(3)
    folder = _write_pair(tmp_path / "seq", lms)
    ids = np.arange(len(lms))
    vis = ids < 3  # only 3 landmarks visible in the target
    write_landmarks(folder / "frame-001.csv", ids, np.where(vis[:, None], _forward(lms), -1), vis)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert "FAILED frame frame-001" in out
    assert "\n1 frame failed; see report.csv" in out  # it said "1 frame(s) failed"
    assert not (tmp_path / "out" / "seq" / "frame-001_theta.npy").exists()
    assert "failed" in (tmp_path / "out" / "seq" / "report.csv").read_text()


def test_landmarks_on_one_line_are_named(tmp_path, capsys):
    """Landmarks on one line fit no spline: the reference's is an error before any work (every frame
    failed, each as "src: the points are collinear"), a target's a failed frame saying why."""
    lms = _grid_landmarks(4)
    ids = np.arange(len(lms))
    first_row = ids < 4  # y = 30 for all four
    folder = _write_pair(tmp_path / "ref", lms)
    write_landmarks(folder / "frame-000-master.csv", ids, np.where(first_row[:, None], lms, -1), first_row)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-progress", "--no-refine"]) == 2
    assert ("the 4 visible landmarks of the reference frame-000-master lie on one line"
            in capsys.readouterr().err)
    assert not (tmp_path / "out").exists()
    folder = _write_pair(tmp_path / "tgt", lms)
    write_landmarks(folder / "frame-001.csv", ids, np.where(first_row[:, None], _forward(lms), -1), first_row)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-progress", "--no-refine"]) == 1
    assert ("FAILED frame frame-001: the 4 landmarks visible in both frames lie on one line (or on one point) in "
            "the reference; a spline needs landmarks spanning the plane" in capsys.readouterr().out)


@pytest.mark.parametrize("case, message", [
    ("off_image", "off the 160x120 image"),
    ("unknown_id", "missing from the reference"),
    ("repeated_id", "repeats ids"),
    ("few_reference", "the reference"),
])
def test_bad_landmarks_are_clear_errors(tmp_path, capsys, case, message):
    lms = _grid_landmarks(3)
    folder = _write_pair(tmp_path / "seq", lms)
    ids = np.arange(len(lms))
    tl = _forward(lms)
    vis = np.ones(len(lms), bool)
    if case == "off_image":
        tl[2] = [W + 5.0, 40.0]
        write_landmarks(folder / "frame-001.csv", ids, tl, vis)
    elif case == "unknown_id":
        write_landmarks(folder / "frame-001.csv", ids + 100, tl, vis)
    elif case == "repeated_id":
        write_landmarks(folder / "frame-001.csv", np.r_[ids[:-1], 0], tl, vis)
    else:
        write_landmarks(folder / "frame-000-master.csv", ids, lms, ids < 3)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_a_frame_failing_a_divergence_test_gets_no_files(tmp_path, monkeypatch):
    """The divergence tests are wired to the report: demand an impossible cost drop and the frame fails."""
    from geofeat.groundtruth import pipeline

    monkeypatch.setattr(pipeline, "MAX_COST_RISE", -1.0)
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    reports = generate_ground_truth(folder, tmp_path / "out", GroundTruthConfig(spacing=16, refine_config=FAST),
                                    progress=False)
    assert reports[0].status == "failed" and "photometric cost rose" in reports[0].reason
    assert not (tmp_path / "out" / "frame-001_theta.npy").exists()
    assert (tmp_path / "out" / "frame-000-master_objmask.png").exists()


def test_splines_keep_the_warps_they_gave_before_moving_to_groundtruth_tps():
    """The splines moved from bench/protocol.py into groundtruth/tps.py, then became the one spline of
    geofeat/tps.py (issue 24): the same warps as the old modules on a fixed example (values recorded
    with the code before the moves; the landmark spline was scipy's RBFInterpolator then)."""
    from geofeat.groundtruth.landmarks import landmark_spline

    rng = np.random.default_rng(24)
    src = rng.uniform(20, 300, (12, 2))
    dst = src + rng.normal(0, 6, (12, 2))
    q = np.array([[100.0, 120.0], [200.0, 80.0], [150.0, 150.0]])
    tps = authors_tps(src, dst, (320, 240))
    theta, ctrl = tps.authors_arrays()
    np.testing.assert_allclose(ThinPlateSpline.from_authors_arrays(theta, ctrl, (320, 240))(q), [
        [106.50807229193813, 120.0470479555451], [208.80008236407267, 77.19345694113082],
        [159.0368820474872, 148.79696056072981]], rtol=0, atol=1e-9)
    np.testing.assert_allclose(landmark_spline(src, dst)(q), [
        [106.06287954378, 120.13740513577952], [211.4988546772442, 76.59430828145304],
        [159.139262678548, 147.6282292593429]], rtol=0, atol=1e-9)
    np.testing.assert_allclose(tps(q), [
        [106.50807496707982, 120.047050449649], [208.800077386238, 77.19344673423106],
        [159.03688765818063, 148.7969673534212]], rtol=0, atol=1e-9)


@pytest.mark.parametrize("source", ["landmarks", "exact"])
def test_map_is_one_interface_for_every_source(tmp_path, simulated, source):
    """`GroundTruth.map(target, xy) -> (xy_ref, valid)`: NaN exactly where not valid, close to the
    truth where valid (the TPS files' source: `test_bench_reads_the_generated_files`)."""
    if source == "landmarks":
        seq = read_sequence(_write_pair(tmp_path / "seq", _grid_landmarks(5)))
        xy = np.array([[W / 2, H / 2], [W / 3, H / 3], [1.0, 1.0], [W - 2.0, 2.0]])  # the last two: outside the hull
        expected_valid = [True, True, False, False]
        truth_xy = _inverse(xy)
    else:
        seq = simulated[0]
        xy = np.random.default_rng(1).uniform([0, 0], [319, 239], (500, 2))
        truth_xy, expected_valid = seq.correspondences(seq.targets[-1], seq.reference, xy)
    truth = GroundTruth(seq, None)
    assert truth.exact == (source == "exact")
    mapped, valid = truth.map(seq.targets[-1], xy)
    assert mapped.shape == xy.shape and valid.shape == (len(xy),) and valid.dtype == bool
    np.testing.assert_array_equal(valid, expected_valid)
    assert np.isnan(mapped[~valid]).all() and np.isfinite(mapped[valid]).all()
    assert np.abs(mapped[valid] - truth_xy[valid]).max() < 1.0


def test_tps_files_map_no_point_off_the_target_image(tmp_path):
    """`GroundTruth.map` with TPS files: a point off the target image is not valid (the object mask
    and the SSIM map were read at the clipped border pixel, so a point 40 px right of the image, or
    50 px above it, was 'valid' with the spline extrapolated there); points on the image are unchanged."""
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(4))
    reports = generate_ground_truth(folder, tmp_path / "tps" / "seq", GroundTruthConfig(refine=False), progress=False)
    assert reports[0].status == "ok"
    truth = GroundTruth(read_sequence(folder), str(tmp_path / "tps"))
    mask = cv2.imread(str(tmp_path / "tps" / "seq" / "frame-001_objmask.png"), cv2.IMREAD_GRAYSCALE)
    assert mask[H // 2, W - 1] and mask[0, W // 2]  # the right and top borders are on the object
    off = np.array([[W + 40.0, H / 2], [W / 2, -50.0], [W - 0.2, H / 2], [W / 2, -0.7]])
    mapped, valid = truth.map("frame-001", off)
    assert not valid.any() and np.isnan(mapped).all()
    on = np.array([[W / 2, H / 2], [W - 0.6, H / 2], [W / 2, 0.0], [W / 2, -0.4]])
    mapped, valid = truth.map("frame-001", on)
    assert valid.all()
    assert np.abs(mapped[0] - _inverse(on[:1])[0]).max() < 1.0


@pytest.mark.parametrize("change, message", [
    (dict(window=6), "window: expected an odd"),  # a torch size mismatch deep inside the refinement
    (dict(window=0), "window: expected an odd"),
    (dict(iterations=()), "iterations: expected"),  # IndexError
    (dict(iterations=(10, -1)), "iterations: expected"),
    (dict(levels=0), "levels: expected"),  # no refinement at all, reported as refined
    (dict(sigma_px=0.0), "sigma_px: expected"),  # the process died (segmentation fault)
    (dict(bending=float("nan")), "bending: expected"),  # the process died too
    (dict(landmarks=-1.0), "landmarks: expected"),
    (dict(flat_tau=0.0), "flat_tau: expected"),
])
def test_refinement_settings_are_checked_before_any_work(tmp_path, change, message):
    from geofeat.groundtruth.pipeline import check_config

    config = GroundTruthConfig(refine_config=RefineConfig(**{**FAST.__dict__, **change}))
    with pytest.raises(ValueError, match=message):
        check_config(config)
    if "window" in change or "iterations" in change:  # safe to run before the fix: a Python error, not a crash
        folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
        with pytest.raises(ValueError, match=message):
            generate_ground_truth(folder, tmp_path / "out", config, progress=False)
        assert not (tmp_path / "out").exists()


def test_landmarks_on_a_line_have_no_inside(tmp_path):
    """The landmark ground truth trusts its spline inside the landmarks' hull: landmarks on a line have
    none, and scipy's QhullError (a RuntimeError, a traceback in `geofeat bench`) said so."""
    from geofeat.groundtruth.landmarks import inside_hull

    line = np.stack([np.linspace(30, 130, 6), np.linspace(30, 90, 6)], 1)
    for points in (line, line[:2], np.repeat(line[:1], 4, axis=0)):
        with pytest.raises(ValueError, match="landmarks: .*collinear or repeated"):
            inside_hull(points, np.array([[50.0, 50.0]]))
    truth = GroundTruth(read_sequence(_write_pair(tmp_path / "seq", line)), None)
    with pytest.raises(ValueError, match="landmarks: .*collinear or repeated"):
        truth.reference_keep(np.array([[W / 2, H / 2]]))
    np.testing.assert_array_equal(inside_hull(_grid_landmarks(3), np.array([[W / 2, H / 2], [1.0, 1.0]])),
                                  [True, False])


def test_overwrite_refuses_a_file_it_would_replace_before_any_frame(tmp_path, monkeypatch, capsys):
    """`--overwrite` never replaces a file geofeat did not write; that was found only when the finished
    result was moved into place, after every frame had been refined."""
    from geofeat.groundtruth import pipeline

    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    for name in ("report.csv", "frame-001_theta.npy"):
        out = tmp_path / name / "seq"
        out.mkdir(parents=True)
        (out / name).write_text("mine")
        monkeypatch.setattr(pipeline, "_frame", lambda *a, **k: pytest.fail("a frame was worked on"))
        assert main(["groundtruth", str(folder), "--out", str(out.parent), "--no-refine", "--no-progress",
                     "--overwrite"]) == 2
        assert f"holds {name}, which geofeat did not write" in capsys.readouterr().err
        assert (out / name).read_text() == "mine"
        with pytest.raises(ValueError, match=f"holds {name}"):
            generate_ground_truth(folder, out, GroundTruthConfig(refine=False), progress=False, overwrite=True)


@pytest.mark.parametrize("level", [1, 2])
def test_the_exact_warp_leaves_no_residual_at_coarse_levels(level):
    """The refinement's pyramid levels (cv2.pyrDown) put level pixel i on full-resolution pixel
    2^l i. They were placed at 2^l (i + 0.5) - 0.5, which cancels for a translation but not for a
    scaled frame: with the exact warp, the coarse levels saw a residual and pulled the field away.
    A linear ramp survives pyrDown's blur unchanged, so the exact warp of a frame at twice the
    reference's scale must reproduce the reference crop at every level."""
    import torch

    from geofeat.groundtruth.photometric import _Level, _warp

    H, W = 240, 320
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    ramp = lambda u, v: (0.2 + 0.002 * u + 0.001 * v).astype(np.float32)  # noqa: E731
    ref, tgt = ramp(x, y), ramp(x / 2, y / 2)  # the frame at twice the scale: tgt(2 p) = ref(p)
    mask = np.zeros((H, W), bool)
    mask[40:100, 40:140] = True  # its image 2 p stays well inside the frame
    gx, gy = np.arange(20.0, 180.0, 16.0), np.arange(20.0, 140.0, 16.0)
    lvl = _Level(ref, tgt, mask, lambda p: 2.0 * p, (30, 30, 150, 110), gx, gy, level, 5, 0.01)
    warped, inside = _warp(lvl, torch.zeros((2, len(gy), len(gx))))
    core = (lvl.mask[0, 0] > 0) & (inside[0, 0] > 0)
    err = (warped[0, 0] - lvl.ref[0, 0])[core].abs().max().item()
    assert err < 1e-4, err  # 7.5e-4 (level 1) and 2.3e-3 (level 2) before


def test_a_frame_whose_refined_spline_fails_reports_the_time_it_took(tmp_path, monkeypatch):
    """A frame whose refined spline could not be fitted returned from its refinement with seconds 0.0
    in report.csv/json, however long the refinement had run. The pipeline's clock is a fake one that
    moves only when the refinement says so: the test checks the report, not the machine's speed."""
    import types

    from geofeat.groundtruth import pipeline

    authors_tps, refine, calls = pipeline.authors_tps, pipeline.refine, []
    clock = types.SimpleNamespace(now=0.0)
    monkeypatch.setattr(pipeline, "time", types.SimpleNamespace(perf_counter=lambda: clock.now))

    def failing_second(*args):
        calls.append(1)
        if len(calls) == 2:  # the spline through the refined nodes
            raise ValueError("no spline")
        return authors_tps(*args)

    def slow_refine(*args, **kw):
        clock.now += 0.3  # the refinement takes 0.3 s
        return refine(*args, **kw)

    monkeypatch.setattr(pipeline, "authors_tps", failing_second)
    monkeypatch.setattr(pipeline, "refine", slow_refine)
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    reports = generate_ground_truth(folder, tmp_path / "out", GroundTruthConfig(spacing=16, refine_config=FAST),
                                    progress=False)
    assert reports[0].status == "failed" and "refinement diverged: no spline" in reports[0].reason
    assert reports[0].seconds >= 0.3


def test_tps_object_mask_is_read_as_the_authors_protocol_reads_it():
    """The authors' matching-score protocol reads an object mask at mask[int(y), int(x)] (truncation):
    x = 3.6 reads pixel 3 and x = 4.6 pixel 4, so that `--tps-dir` scores are theirs. Off the image
    (outside -0.5 .. W - 0.5) is off the mask, not the border pixel."""
    from geofeat.groundtruth.sources import _on_mask

    mask = np.zeros((10, 10), np.uint8)
    mask[:, 4] = 255  # only column 4 is on the object
    xs = np.array([3.4, 3.6, 4.0, 4.4, 4.6, 4.99, 5.0])
    on = _on_mask(mask, np.stack([xs, np.full_like(xs, 5.0)], axis=1))
    assert on.tolist() == [False, False, True, True, True, True, False]
    ys = np.array([-0.4, 9.4, 9.6])  # the image's edge: -0.5 .. H - 0.5
    assert _on_mask(np.ones((10, 10), np.uint8), np.stack([np.full_like(ys, 5.0), ys], axis=1)).tolist() == [True, True, False]


def test_reference_mask_holds_every_landmark_pixel_with_no_margin():
    """The hull of the landmarks is drawn through their nearest pixels: with --margin 0 the pixel under
    each landmark is on the object (truncation drew it through 20 for a landmark at 20.9)."""
    from geofeat.frame import RGBDFrame
    from geofeat.groundtruth import reference_mask

    frame = RGBDFrame(np.full((32, 32), 0.5, np.float32), np.ones((32, 32)),
                      np.array([[30.0, 0, 15.5], [0, 30.0, 15.5], [0, 0, 1]]))
    lm = np.array([[10.9, 10.9], [20.9, 10.9], [20.9, 20.9], [10.9, 20.9], [15.6, 20.7]])
    mask = reference_mask(frame, lm, margin_px=0.0, depth_margin_m=0.1)
    px = np.rint(lm).astype(int)
    assert mask[px[:, 1], px[:, 0]].all()


def test_leave_one_out_residual_of_four_landmarks_is_the_affine_prediction():
    """With 4 landmarks, leaving one out leaves 3, whose affine map predicts the fourth: its error is the
    leave-one-out residual (reported as 0 px, a perfect fit, before)."""
    rng = np.random.default_rng(1)
    src = rng.uniform(20, 140, (4, 2))
    dst = src + rng.normal(0, 3, (4, 2))
    expected = []
    for i in range(4):
        affine = np.linalg.solve(np.c_[np.delete(src, i, 0), np.ones(3)], np.delete(dst, i, 0))
        expected.append(np.linalg.norm(np.r_[src[i], 1.0] @ affine - dst[i]))
    fit = robust_landmark_tps(src, dst, (W, H))
    assert fit.inliers.all()
    np.testing.assert_allclose(fit.loo_px, expected, rtol=1e-6)
    assert min(expected) > 1.0


def test_tps_files_for_another_image_size_are_refused(tmp_path):
    """TPS files made for 160x120 frames, read with the same sequence at 320x240: the spline, normalised
    by the mask's size, mapped a 320x240 keypoint (100, 100) to (100.9, 104.1), 9.7 px from the truth
    (91.4, 98.4), and called it valid."""
    from geofeat.io import read_depth, read_image, read_landmarks

    folder = _write_pair(tmp_path / "seq", _grid_landmarks(4))
    generate_ground_truth(read_sequence(folder), tmp_path / "gt" / "seq", GroundTruthConfig(refine=False), progress=False)
    big = tmp_path / "big" / "seq"
    big.mkdir(parents=True)
    for name in ("frame-000-master", "frame-001"):
        write_frame(big, name, cv2.resize(read_image(folder / f"{name}-rgb.png"), (2 * W, 2 * H)),
                    cv2.resize(read_depth(folder / f"{name}-depth.png"), (2 * W, 2 * H), interpolation=cv2.INTER_NEAREST))
        ids, xy, visible = read_landmarks(folder / f"{name}.csv")
        write_landmarks(big / f"{name}.csv", ids, xy * 2, visible)
    write_intrinsics(big / "intrinsics.xml", np.array([[200.0, 0, W], [0, 200.0, H], [0, 0, 1]]))
    small = GroundTruth(read_sequence(folder), str(tmp_path / "gt")).map("frame-001", np.array([[50.0, 50.0]]))
    assert small[1].all() and np.linalg.norm(small[0] - _inverse(np.array([[50.0, 50.0]]))) < 1.0
    truth = GroundTruth(read_sequence(big), str(tmp_path / "gt"))
    with pytest.raises(ValueError, match=r"tps-dir: .*frame-001_objmask.png is 160x120, the frames of .* 320x240"):
        truth.map("frame-001", np.array([[100.0, 100.0]]))
    with pytest.raises(ValueError, match="is 160x120"):
        truth.reference_keep(np.array([[100.0, 100.0]]))


def test_an_ssim_map_of_another_size_or_unreadable_is_refused(tmp_path):
    """The object masks were checked against the frames' size, the SSIM map was not: one of half the
    size, read at the keypoints' pixels, kept only the target keypoints in its top-left quarter (in a
    bench run MS 0.54 became 0.67 on 3 of 54 target keypoints, without a word), and an unreadable one
    was taken for none (no SSIM test at all)."""
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(4))
    generate_ground_truth(read_sequence(folder), tmp_path / "gt" / "seq", GroundTruthConfig(refine=False), progress=False)
    points = np.array([[30.0, 30.0], [120.0, 90.0]])  # one in each half of the 160x120 frame
    mapped, valid = GroundTruth(read_sequence(folder), str(tmp_path / "gt")).map("frame-001", points)
    assert valid.all()
    ssim_path = tmp_path / "gt" / "seq" / "frame-001_SSIM.png"
    ssim = cv2.imread(str(ssim_path), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(ssim_path), cv2.resize(ssim, (W // 2, H // 2), interpolation=cv2.INTER_NEAREST))
    truth = GroundTruth(read_sequence(folder), str(tmp_path / "gt"))
    with pytest.raises(ValueError, match=r"tps-dir: .*frame-001_SSIM.png is 80x60, the frames of .* 160x120"):
        truth.map("frame-001", points)
    ssim_path.write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"frame-001_SSIM.png is not an image"):
        truth.map("frame-001", points)
    ssim_path.unlink()  # no SSIM map: the object mask alone decides, as before
    np.testing.assert_array_equal(truth.map("frame-001", points)[1], valid)


def test_tps_files_of_one_sequence_name_in_two_datasets_are_refused(tmp_path):
    """--tps-dir holding kinect1/seq and kinect2/seq: the first by name was used for the sequence `seq`
    without a word, whichever dataset it came from."""
    from geofeat.groundtruth.sources import tps_folder

    for dataset in ("kinect2", "kinect1"):
        (tmp_path / dataset / "seq").mkdir(parents=True)
        (tmp_path / dataset / "seq" / "frame-001_theta.npy").write_bytes(b"")
    with pytest.raises(ValueError, match=r"tps-dir: 2 folders hold TPS files for sequence seq .*kinect1/seq, .*kinect2/seq"):
        tps_folder(str(tmp_path), "seq")
    assert tps_folder(str(tmp_path / "kinect2"), "seq") == tmp_path / "kinect2" / "seq"
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "frame-001_theta.npy").write_bytes(b"")
    assert tps_folder(str(tmp_path), "seq") == tmp_path / "seq"  # named directly: not ambiguous


def test_resume_keeps_a_sequence_finished_under_another_spelling_of_its_folder(tmp_path, capsys, monkeypatch):
    """report.json recorded the sequence folder as given ("seq"), and --resume naming the same folder
    another way ("/abs/seq") refused the finished result as made "from seq, not /abs/seq"."""
    _write_pair(tmp_path / "seq", _grid_landmarks(3))
    monkeypatch.chdir(tmp_path)
    assert main(["groundtruth", "seq", "--out", "out", "--no-refine", "--no-progress"]) == 0
    kept = (tmp_path / "out" / "seq" / "report.json").stat().st_mtime_ns
    capsys.readouterr()
    assert main(["groundtruth", str(tmp_path / "seq"), "--out", str(tmp_path / "out"), "--no-refine",
                 "--no-progress", "--resume"]) == 0
    assert "kept 1 sequence finished by an earlier run: seq" in capsys.readouterr().out
    assert (tmp_path / "out" / "seq" / "report.json").stat().st_mtime_ns == kept


def test_a_larger_target_frame_fails_alone_not_the_run(tmp_path, capsys):
    """A target at twice the reference's size, its landmarks on its own pixels: they lie off the
    reference's image, and the whole run stopped, saying they were off a 160x120 image; it is a
    failed frame naming both sizes, as a smaller one is, and the other targets are written."""
    lms = _grid_landmarks(3)
    folder = _write_pair(tmp_path / "seq", lms)
    for suffix in ("-rgb.png", "-depth.png", ".csv"):
        shutil.copy(folder / f"frame-001{suffix}", folder / f"frame-002{suffix}")
    big = cv2.resize(cv2.imread(str(folder / "frame-001-rgb.png")), (2 * W, 2 * H))
    write_frame(folder, "frame-001", big, np.full((2 * H, 2 * W), 1.0))
    write_landmarks(folder / "frame-001.csv", np.arange(len(lms)), 2 * _forward(lms), np.ones(len(lms), bool))
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-refine", "--no-progress"]) == 1
    printed = capsys.readouterr().out
    assert "FAILED frame frame-001" in printed and "320x240 differs in size from the reference" in printed
    assert (tmp_path / "out" / "seq" / "frame-002_theta.npy").is_file()
    assert not (tmp_path / "out" / "seq" / "frame-001_theta.npy").exists()


def test_spacing_without_refinement_is_refused(tmp_path, capsys):
    """--spacing sets the refinement's grid: with --no-refine it was accepted and did nothing (and a
    --resume with another --spacing was refused as "other settings")."""
    folder = _write_pair(tmp_path / "seq", _grid_landmarks(3))
    args = ["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-refine", "--no-progress"]
    assert main([*args, "--spacing", "8"]) == 2
    assert "--spacing: 8 is the control-point spacing of the photometric refinement" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    assert main(args) == 0


def test_a_frame_whose_landmark_ids_are_shuffled_fails(tmp_path, capsys):
    """Target landmarks whose ids name other points than the reference's: no landmark stands out, so
    none was rejected, and the landmark-only spline (folding over the frame) was written as "ok"."""
    lms = _grid_landmarks(5)
    shuffled = _forward(lms)[np.random.default_rng(0).permutation(len(lms))]
    folder = _write_pair(tmp_path / "seq", lms, shuffled)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out"), "--no-refine", "--no-progress"]) == 1
    assert "FAILED frame frame-001: the landmarks disagree" in capsys.readouterr().out
    assert not (tmp_path / "out" / "seq" / "frame-001_theta.npy").exists()
    report = json.loads((tmp_path / "out" / "seq" / "report.json").read_text())["frames"][0]
    assert report["status"] == "failed" and report["loo_median_px"] > 25
    # the analytic warp's own landmarks pass
    folder = _write_pair(tmp_path / "good", lms)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "out2"), "--no-refine", "--no-progress"]) == 0


def test_simulator_truth_of_another_size_than_the_frames_is_refused(tmp_path, simulated):
    """Frames halved after simulation, their `<frame>-gt.npz` kept: the uv maps were read at the small
    frames' pixels, every point looked up at another place of the cloth, and the bench said the ground
    truth "covers no pixel of the reference frame (no object there)"."""
    from geofeat.io import read_intrinsics

    seq = read_sequence(shutil.copytree(simulated[0].folder, tmp_path / "half"))
    for name in seq.names:
        frame = seq.frame(name)
        h, w = frame.shape[0] // 2, frame.shape[1] // 2
        write_frame(seq.folder, name, cv2.resize(cv2.imread(str(seq.folder / f"{name}-rgb.png")), (w, h)),
                    cv2.resize(frame.depth, (w, h), interpolation=cv2.INTER_NEAREST), seq.depth_scale)
    K = read_intrinsics(seq.folder / "intrinsics.xml")
    K[:2] /= 2
    write_intrinsics(seq.folder / "intrinsics.xml", K)
    half = read_sequence(seq.folder)
    with pytest.raises(ValueError, match=r"frame-001-gt.npz: the simulator's ground truth is 320x240, the "
                                         r"frames of .* 160x120"):
        half.correspondences(half.targets[0], half.reference, np.array([[80.0, 60.0]]))
    assert simulated[0].correspondences(simulated[0].targets[0], simulated[0].reference,
                                        np.array([[160.0, 120.0]]))[0].shape == (1, 2)


@pytest.mark.parametrize("stride", [0, -4])
def test_mapping_errors_refuses_a_stride_below_one(tmp_path, stride):
    """stride=0 raised numpy's bare ZeroDivisionError from np.arange; a negative one compared no pixel."""
    from geofeat.io import demo_data_dir

    seq = read_sequence(demo_data_dir())
    with pytest.raises(ValueError, match=rf"stride: expected a whole number >= 1, got {stride}"):
        mapping_errors(seq, tmp_path, seq.reference, stride=stride)


def _wall_behind(seq_folder: Path, depth_m: float = 1.5):
    """Give a simulated sequence's background (no depth from the simulator) the depth of a wall
    `depth_m` metres away, as a Kinect sees the wall behind the cloth; returns the sequence and
    {frame: (H, W) bool cloth pixels of the exact ground truth}."""
    from geofeat.groundtruth.simulator import read_frame_truth

    seq = read_sequence(seq_folder)
    cloth = {name: read_frame_truth(seq.folder, name).uv[..., 0] >= 0 for name in seq.names}
    for name in seq.names:
        write_frame(seq.folder, name, cv2.imread(str(seq.folder / f"{name}-rgb.png")),
                    np.where(cloth[name], seq.frame(name).depth, depth_m), seq.depth_scale)
    return read_sequence(seq.folder), cloth


def test_a_landmark_clicked_on_the_background_does_not_widen_the_object_mask(tmp_path, simulated):
    """One reference landmark clicked just off the cloth, onto the wall 0.5 m behind it: its depth
    stretched the mask's depth range to the wall and its hull over it, and 81 % of the reference
    object mask was wall (the exact ground truth tells cloth from wall). It is named and left out."""
    seq, cloth = _wall_behind(shutil.copytree(simulated[0].folder, tmp_path / "wall"))
    ids, xy, vis = seq.landmarks(seq.reference)
    ref_cloth = cloth[seq.reference]
    wall = np.argwhere(cv2.distanceTransform((~ref_cloth).astype(np.uint8), cv2.DIST_L2, 5) >= 4)
    xy[0] = wall[np.argmin(np.hypot(*(wall - xy[0, ::-1]).T))][::-1]  # the wall pixel nearest to it
    write_landmarks(seq.folder / f"{seq.reference}.csv", ids, xy, vis)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        generate_ground_truth(seq, tmp_path / "gt", GroundTruthConfig(refine=False), progress=False)
    for name in seq.names:
        mask = cv2.imread(str(tmp_path / "gt" / f"{name}_objmask.png"), cv2.IMREAD_GRAYSCALE) > 0
        assert (mask & ~cloth[name]).sum() < 0.02 * mask.sum(), name  # was 81 % wall in the reference
        assert (mask & cloth[name]).sum() > 0.9 * cloth[name].sum(), name
    said = [str(w.message) for w in caught if "cut off from the other landmarks'" in str(w.message)]
    assert len(said) == 1 and re.match(rf"landmarks: {seq.reference}.csv ids \[{ids[0]}\] lie at depth 1.50 m, cut off "
                                       r"from the other landmarks' 0.9[0-9]-1.0[0-9] m", said[0]), said


@pytest.mark.parametrize("slip, message", [
    ("double size", "with its coordinates scaled by 0.5 (annotated on 320x240 frames?)"),
    ("half size", "with its coordinates scaled by 2 (annotated on 80x60 frames?)"),
    ("ids off by one", "with its id k taken for the reference's id k+1 (ids off by one?)"),
])
def test_a_frame_whose_landmarks_slipped_fails(tmp_path, capsys, slip, message):
    """Landmarks consistent with one another but not with the image: annotated on frames of twice or
    half the size (all still on the 160x120 image), or with the ids shifted by one along the grid's
    rows. The leave-one-out check passed them and the spline, mapping the frame onto the wrong part of
    the reference, was written as "ok"; the same landmarks annotated right pass."""
    corner = np.stack(np.meshgrid(np.linspace(12, 68, 4), np.linspace(12, 50, 3)), -1).reshape(-1, 2)
    lms = corner if slip == "double size" else _grid_landmarks(5)
    right = _forward(lms)
    ids = np.arange(len(lms))
    folder = _write_pair(tmp_path / "right", lms)
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "gt-right"), "--no-refine", "--no-progress"]) == 0
    folder = _write_pair(tmp_path / "seq", lms)
    if slip == "ids off by one":  # the target's id k is the reference's point k + 1
        write_landmarks(folder / "frame-001.csv", ids[:-1], right[1:], np.ones(len(ids) - 1, bool))
    else:
        scale = 2.0 if slip == "double size" else 0.5
        write_landmarks(folder / "frame-001.csv", ids, (right + 0.5) * scale - 0.5, np.ones(len(ids), bool))
    assert main(["groundtruth", str(folder), "--out", str(tmp_path / "gt"), "--no-refine", "--no-progress"]) == 1
    printed = capsys.readouterr().out
    assert ("FAILED frame frame-001: frame-001.csv looks slipped: the image at the landmarks matches the reference "
            f"{message}: median NCC") in printed, printed
    assert not (tmp_path / "gt" / "seq" / "frame-001_theta.npy").exists()
