"""Bad and edge inputs for every command (issue 22): each is a clear one-line error (exit 2), a frame
skipped by name (exit 1), an interrupt (exit 130), or a correct result; no run deletes or corrupts
anything a user had. One table row per case; a property test of `polar_patches` at the end."""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geofeat
from geofeat.cli import main
from geofeat.io import read_landmarks, read_sequence, write_frame, write_intrinsics, write_landmarks

W, H = 160, 120
K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
SHIFT = 3  # the target frame is the reference moved SHIFT px to the right


def _texture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = sum(cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), s) * s for s in (1.5, 4))
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def _landmarks() -> np.ndarray:
    gx, gy = np.meshgrid(np.linspace(20, W - 30, 5), np.linspace(20, H - 20, 4))
    return np.stack([gx.ravel(), gy.ravel()], 1)


def make_sequence(folder: Path, names=("frame-000-master", "frame-001"), depth_m: float = 1.0,
                  landmarks: bool = True) -> Path:
    """A small sequence in the public layout: mm depth PNGs, shifted texture, landmark csvs."""
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder / "intrinsics.xml", K)
    ref = _texture()
    lm = _landmarks()
    for i, name in enumerate(names):
        image = np.roll(ref, SHIFT * i, axis=1)
        write_frame(folder, name, cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), np.full((H, W), depth_m))
        if landmarks:
            write_landmarks(folder / f"{name}.csv", np.arange(len(lm)), lm + [SHIFT * i, 0], np.ones(len(lm), bool))
    return folder


@dataclass
class Case:
    """One bad input: `setup(tmp)` builds the inputs and returns the command line (paths under tmp);
    the command must exit with `code` and print `message` (regex) on one stderr line (exit 2) or
    anywhere (other codes); `check(tmp)` then asserts what must hold on disk."""

    id: str
    setup: Callable[[Path], list[str]]
    code: int
    message: str = ""
    check: Callable[[Path], None] | None = None
    patch: Callable[[pytest.MonkeyPatch], None] | None = field(default=None)


# ---------------------------------------------------------------- setups
def _seq(tmp: Path, **kw) -> Path:
    return make_sequence(tmp / "seq", **kw)


def _user_files(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "thesis.txt").write_text("years of work")
    (folder / "sub").mkdir(exist_ok=True)
    (folder / "sub" / "notes.md").write_text("notes")


def _user_files_kept(folder: Path) -> None:
    assert (folder / "thesis.txt").read_text() == "years of work"
    assert (folder / "sub" / "notes.md").read_text() == "notes"


def simulate_over_user_files(tmp):
    _user_files(tmp / "out")
    return ["simulate", str(tmp / "out"), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
            "--texture", "procedural", "--overwrite"]


def simulate_over_earlier_simulation_plus_user_file(tmp):
    assert main(["simulate", str(tmp / "out"), "--frames", "3", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural"]) == 0
    (tmp / "out" / "thesis.txt").write_text("years of work")
    return ["simulate", str(tmp / "out"), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
            "--texture", "procedural", "--overwrite"]


def simulate_over_earlier_simulation(tmp):
    assert main(["simulate", str(tmp / "out"), "--frames", "4", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural"]) == 0
    return ["simulate", str(tmp / "out"), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
            "--texture", "procedural", "--overwrite"]


def _two_frames_exactly(tmp):
    assert len(read_sequence(tmp / "out")) == 2  # nothing stale of the 4-frame run is left


def extract_over_existing(tmp):
    (tmp / "f.h5").write_bytes(b"earlier results")
    return ["extract", str(_seq(tmp)), "--descriptor", "sift", "--out", str(tmp / "f.h5")]


def _earlier_h5_kept(tmp):
    assert (tmp / "f.h5").read_bytes() == b"earlier results"


def _fail_second_save(monkeypatch):
    import geofeat.features as features

    original, calls = features.save_features, []

    def failing(path, f, name=None):
        calls.append(name)
        if len(calls) == 2:
            raise OSError("disk full (simulated)")
        return original(path, f, name=name)

    monkeypatch.setattr(features, "save_features", failing)


def extract_error_midway(tmp):
    (tmp / "f.h5").write_bytes(b"earlier results")
    return ["extract", str(_seq(tmp)), "--descriptor", "sift", "--out", str(tmp / "f.h5"), "--overwrite"]


def _no_partial_files(tmp):
    _earlier_h5_kept(tmp)
    assert not [p for p in tmp.iterdir() if "partial" in p.name]


def match_into_user_folder(tmp):
    _user_files(tmp / "m")
    return ["match", str(_seq(tmp)), "--descriptor", "sift", "--out", str(tmp / "m")]


def match_overwrite_keeps_user_files(tmp):
    seq = _seq(tmp)
    assert main(["match", str(seq), "--descriptor", "sift", "--out", str(tmp / "m"), "--keypoints", "200"]) == 0
    (tmp / "m" / "thesis.txt").write_text("years of work")
    (tmp / "m" / "sub").mkdir()
    (tmp / "m" / "sub" / "notes.md").write_text("notes")
    return ["match", str(seq), "--descriptor", "sift", "--out", str(tmp / "m"), "--keypoints", "200", "--overwrite"]


def _matches_and_user_files(tmp):
    _user_files_kept(tmp / "m")
    assert geofeat.load_matches(tmp / "m" / "matches-sift.h5", name="frame-000-master/frame-001") is not None


def _bench_args(tmp, *datasets, extra=()):
    return ["bench", *map(str, datasets), "--descriptors", "sift", "--keypoints", "200", "--out", str(tmp / "b"),
            *extra]


def _two_datasets(tmp):
    make_sequence(tmp / "ds" / "s1")
    make_sequence(tmp / "ds" / "s2")
    return tmp / "ds"


def bench_partial_row(tmp):
    ds = _two_datasets(tmp)
    assert main(_bench_args(tmp, ds)) == 0
    text = (tmp / "b" / "results.csv").read_text()
    (tmp / "b" / "results.csv").write_text(text[: len(text) - 25])  # killed during the append
    return _bench_args(tmp, ds)


def bench_unparsable_row(tmp):
    ds = _two_datasets(tmp)
    assert main(_bench_args(tmp, ds)) == 0
    lines = (tmp / "b" / "results.csv").read_text().splitlines(keepends=True)
    (tmp / "b" / "results.csv").write_text("".join(lines[:-1]) + "s2,frame-000-master,fra\x00garbage\n")
    return _bench_args(tmp, ds)


def _results_complete(tmp):
    import csv

    rows = list(csv.DictReader(open(tmp / "b" / "results.csv")))
    assert sorted(r["sequence"] for r in rows) == ["s1", "s2"]
    assert all(r["scale"] not in (None, "") for r in rows)
    assert (tmp / "b" / "table.md").is_file()


def _interrupt_in_walk(monkeypatch):
    import geofeat.bench.runner as runner

    def interrupted(*args, **kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as error:  # how numba surfaces Ctrl-C
            raise SystemError("<numba function> returned a result with an exception set") from error

    monkeypatch.setattr(runner, "evaluate_sequence", interrupted)


def bench_interrupted(tmp):
    return _bench_args(tmp, _two_datasets(tmp))


def _no_table(tmp):
    assert not (tmp / "b" / "table.md").exists()


def _interrupt_extract(monkeypatch):
    import geofeat.keypoints as keypoints

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(keypoints, "detect", interrupted)


def extract_interrupted(tmp):
    return ["extract", str(_seq(tmp)), "--descriptor", "sift", "--out", str(tmp / "f.h5")]


def _nothing_written(tmp):
    assert not (tmp / "f.h5").exists() and not [p for p in tmp.iterdir() if "partial" in p.name]


def bench_duplicate_names(tmp):
    make_sequence(tmp / "dsA" / "cloth")
    make_sequence(tmp / "dsB" / "cloth")
    return _bench_args(tmp, tmp / "dsA", tmp / "dsB")


def bench_same_folder_twice(tmp):
    make_sequence(tmp / "ds" / "s1")
    return _bench_args(tmp, tmp / "ds", tmp / "ds" / "s1")


def _one_sequence(tmp):
    import csv

    rows = list(csv.DictReader(open(tmp / "b" / "results.csv")))
    assert [r["sequence"] for r in rows] == ["s1"]


def bench_missing_tps_dir(tmp):
    return _bench_args(tmp, _seq(tmp), extra=["--tps-dir", str(tmp / "nope")])


def bench_keypoint_set_with_geokey(tmp):
    return _bench_args(tmp, _seq(tmp), extra=["--detector", "geokey", "--keypoint-set", "unique"])


def extract_keypoint_set_with_geokey(tmp):
    # geobit's detector is GeoKey unless --detector sift: a SIFT-only option must not be ignored
    return ["extract", str(_seq(tmp)), "--descriptor", "geobit", "--keypoint-set", "protocol",
            "--out", str(tmp / "f.h5")]


def bench_empty_tps_folder(tmp):
    (tmp / "gt" / "seq").mkdir(parents=True)  # named like the sequence, no TPS files in it
    return _bench_args(tmp, _seq(tmp), extra=["--tps-dir", str(tmp / "gt")])


def extract_json_radius(tmp):
    seq = _seq(tmp)
    (seq / "geofeat.json").write_text(json.dumps({"radius": 0.04}))
    assert main(["extract", str(seq), "--descriptor", "geobit", "--keypoints", "40", "--radius", "0.04",
                 "--out", str(tmp / "explicit.h5")]) == 0
    return ["extract", str(seq), "--descriptor", "geobit", "--keypoints", "40", "--out", str(tmp / "json.h5")]


def _same_descriptors_as_explicit_radius(tmp):
    a = geofeat.load_features(tmp / "explicit.h5", name="frame-001")
    b = geofeat.load_features(tmp / "json.h5", name="frame-001")
    assert np.array_equal(a.descriptors, b.descriptors)


def _off_image_landmark(tmp, command: str) -> list[str]:
    seq = _seq(tmp)
    ids, xy, vis = read_landmarks(seq / "frame-001.csv")
    xy[3] = [W + 20, 40]  # 20 px off the image
    write_landmarks(seq / "frame-001.csv", ids, xy, vis)
    if command == "match":
        return ["match", str(seq), "--descriptor", "sift", "--out", str(tmp / "m")]
    return _bench_args(tmp, seq, extra=["--protocol", "landmarks"] if command == "bench-landmarks" else [])


def metres_under_mm_scale(tmp):
    seq = _seq(tmp, depth_m=1.0)
    depth = np.full((H, W), 2, np.uint16)  # 2 "mm": metres stored as integers
    for name in ("frame-000-master", "frame-001"):
        cv2.imwrite(str(seq / f"{name}-depth.png"), depth)
    return ["extract", str(seq), "--descriptor", "sift", "--out", str(tmp / "f.h5")]


def _with_K(matrix) -> Callable[[Path], list[str]]:
    def setup(tmp):
        seq = _seq(tmp)
        write_intrinsics(seq / "intrinsics.xml", np.asarray(matrix, float))
        return ["extract", str(seq), "--descriptor", "sift", "--out", str(tmp / "f.h5")]

    return setup


def preflight_is_not_the_reference(tmp):
    make_sequence(tmp / "seq", names=("cloth_frame0", "cloth_preflight"))
    return ["match", str(tmp / "seq"), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "m")]


def _reference_is_frame0(tmp):
    assert read_sequence(tmp / "seq").reference == "cloth_frame0"
    assert (tmp / "m" / "cloth_frame0__cloth_preflight__sift.png").is_file()


def _gt(tmp, *extra, seq=None):
    seq = seq or _seq(tmp)
    return ["groundtruth", str(seq), "--out", str(tmp / "gt"), "--no-progress", "--no-refine", *extra]


def groundtruth_object_moves_back(tmp):
    """The target is the reference seen 0.5 m further back (another renderer's scale scenario)."""
    seq = _seq(tmp)
    write_frame(seq, "frame-001", cv2.imread(str(seq / "frame-001-rgb.png")), np.full((H, W), 1.5))
    return _gt(tmp, seq=seq)


def _report_finite_ok(tmp):
    import csv

    rows = list(csv.DictReader(open(tmp / "gt" / "seq" / "report.csv")))
    assert rows and all(r["status"] == "ok" for r in rows)
    assert all(np.isfinite(float(r["ssim_before"])) and np.isfinite(float(r["ssim_after"])) for r in rows)
    assert float(rows[0]["ssim_after"]) > 0.5
    assert cv2.imread(str(tmp / "gt" / "seq" / "frame-001_SSIM.png"), cv2.IMREAD_GRAYSCALE).max() > 100


def retrieval_single_frame(tmp):
    make_sequence(tmp / "seq", names=("frame-000-master",))
    return ["retrieval", str(tmp / "seq"), "--descriptors", "sift", "--include-own-sequence", "--out", str(tmp / "r")]


def retrieval_negative_rerank(tmp):
    make_sequence(tmp / "seq")
    return ["retrieval", str(tmp / "seq"), "--descriptors", "sift", "--rerank", "-1", "--out", str(tmp / "r")]


def _out_is_file(command: str) -> Callable[[Path], list[str]]:
    def setup(tmp):
        seq = _seq(tmp)
        (tmp / "taken").write_text("a file")
        head = {"bench": ["bench", str(seq), "--descriptors", "sift"],
                "match": ["match", str(seq), "--descriptor", "sift"],
                "track": ["track", str(seq), "--descriptors", "sift"],
                "retrieval": ["retrieval", str(seq), "--descriptors", "sift"],
                "groundtruth": ["groundtruth", str(seq), "--no-progress"],
                "extract": ["extract", str(seq), "--descriptor", "sift"]}[command]
        return head + ["--out", str(tmp / "taken")]

    return setup


def _file_kept(tmp):
    assert (tmp / "taken").read_text() == "a file"


def _intrinsics_text(text: str) -> Callable[[Path], list[str]]:
    def setup(tmp):
        seq = _seq(tmp)
        (seq / "intrinsics.xml").write_text(text)
        return ["extract", str(seq), "--descriptor", "sift", "--out", str(tmp / "f.h5")]

    return setup


def _config(text: str, command: str = "extract") -> Callable[[Path], list[str]]:
    def setup(tmp):
        seq = _seq(tmp)
        (seq / "geofeat.json").write_text(text)
        if command == "bench":
            return _bench_args(tmp, seq)
        return ["extract", str(seq), "--descriptor", "sift", "--out", str(tmp / "f.h5")]

    return setup


def _no_depth_frame(command: str) -> Callable[[Path], list[str]]:
    def setup(tmp):
        seq = make_sequence(tmp / "seq", names=("frame-000-master", "frame-001", "frame-002"))
        cv2.imwrite(str(seq / "frame-001-depth.png"), np.zeros((H, W), np.uint16))
        if command == "extract":
            return ["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "f.h5")]
        if command == "match":
            return ["match", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "m")]
        if command == "track":
            return ["track", str(seq), "--descriptors", "sift", "--keypoints", "300", "--out", str(tmp / "t")]
        return ["retrieval", str(seq), "--descriptors", "sift", "--keypoints", "200", "--samples", "200",
                "--words", "3", "--include-own-sequence", "--out", str(tmp / "r")]

    return setup


def _extract_kept_other_frames(tmp):
    from geofeat.features import list_names

    assert sorted(list_names(tmp / "f.h5")) == ["frame-000-master", "frame-002"]


def extract_npz_rerun_skipping_a_frame(tmp):
    """`--out f.npz --overwrite` over an earlier run, now skipping frame-001: its earlier
    f-frame-001.npz was left beside this run's files (other keypoints, other settings) without a word."""
    seq = make_sequence(tmp / "seq", names=("frame-000-master", "frame-001", "frame-002"))
    args = ["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "f.npz")]
    assert main(args) == 0 and (tmp / "f-frame-001.npz").is_file()
    cv2.imwrite(str(seq / "frame-001-depth.png"), np.zeros((H, W), np.uint16))
    return args + ["--overwrite"]


def _no_stale_npz(tmp):
    assert sorted(p.name for p in tmp.glob("f-*.npz")) == ["f-frame-000-master.npz", "f-frame-002.npz"]


def _match_kept_other_frames(tmp):
    assert (tmp / "m" / "frame-000-master__frame-002__sift.png").is_file()


def _retrieval_written(tmp):
    assert "SKIPPED frames: seq/frame-001" in (tmp / "r" / "retrieval.md").read_text()


def _landmark_csv(text: str) -> Callable[[Path], list[str]]:
    def setup(tmp):
        seq = _seq(tmp)
        (seq / "frame-001.csv").write_text(text)
        return ["match", str(seq), "--descriptor", "sift", "--out", str(tmp / "m")]

    return setup


def depth_size_differs(tmp):
    seq = _seq(tmp)
    cv2.imwrite(str(seq / "frame-001-depth.png"), np.full((H // 2, W // 2), 1000, np.uint16))
    return ["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "f.h5")]


def two_references(tmp):
    make_sequence(tmp / "seq", names=("a_ref", "b_master"))
    return ["extract", str(tmp / "seq"), "--descriptor", "sift", "--out", str(tmp / "f.h5")]


def depth_8bit(tmp):
    seq = _seq(tmp)
    cv2.imwrite(str(seq / "frame-000-master-depth.png"), np.full((H, W), 100, np.uint8))
    return ["extract", str(seq), "--descriptor", "sift", "--out", str(tmp / "f.h5")]


def corrupt_colour_frame(tmp):
    seq = make_sequence(tmp / "seq", names=("frame-000-master", "frame-001", "frame-002"))
    (seq / "frame-001-rgb.png").write_bytes(b"\x89PNG truncated")
    return ["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "f.h5")]


def bench_into_user_folder(tmp):
    _user_files(tmp / "b")
    return _bench_args(tmp, _seq(tmp))


def bench_overwrite_foreign_results_csv(tmp):
    (tmp / "b").mkdir()
    (tmp / "b" / "results.csv").write_text("my,own,table\n1,2,3\n")
    return _bench_args(tmp, _seq(tmp), extra=["--overwrite"])


def bench_overwrite_user_config_json(tmp):
    """A folder of the user's without results.csv: `--overwrite` used to replace their config.json and
    table.md with the bench's."""
    _user_files(tmp / "b")
    (tmp / "b" / "config.json").write_text('{"mine": 1}')
    return _bench_args(tmp, _seq(tmp), extra=["--overwrite"])


def _user_config_kept(tmp):
    _user_files_kept(tmp / "b")
    assert (tmp / "b" / "config.json").read_text() == '{"mine": 1}'
    assert not (tmp / "b" / "results.csv").exists()


def bench_huge_keypoint_budget(tmp):
    """More keypoints than OpenCV's int: every sequence used to fail with "OpenCV ... Bad argument in
    function 'SIFT_create'"; a budget above what a frame has returns them all."""
    args = _bench_args(tmp, _seq(tmp))
    args[args.index("--keypoints") + 1] = "3000000000"
    return args


def _foreign_csv_kept(tmp):
    assert (tmp / "b" / "results.csv").read_text() == "my,own,table\n1,2,3\n"


def extract_out_under_file(tmp):
    (tmp / "taken").write_text("a file")
    return ["extract", str(_seq(tmp)), "--descriptor", "sift", "--out", str(tmp / "taken" / "f.h5")]


def _frame_of_another_size(command: str) -> Callable[[Path], list[str]]:
    """frame-001 at twice the reference's size: the sequence's one intrinsics matrix is the
    reference's, so its geodesic patches (and its landmarks' check) would use another camera."""
    def setup(tmp):
        seq = make_sequence(tmp / "seq", names=("frame-000-master", "frame-001", "frame-002"))
        image = cv2.resize(cv2.imread(str(seq / "frame-001-rgb.png")), (2 * W, 2 * H))
        write_frame(seq, "frame-001", image, np.ones((2 * H, 2 * W)))
        if command == "extract":
            return ["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "f.h5")]
        return ["match", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "m")]

    return setup


def extract_out_in_other_case(tmp):
    return ["extract", str(_seq(tmp)), "--descriptor", "sift", "--keypoints", "50", "--out", str(tmp / "f.HDF5")]


def _features_file_in_other_case(tmp):
    """save_features takes .hdf5 / .H5 / .NPZ; extract made a folder of that name with features-sift.h5 in it."""
    assert (tmp / "f.HDF5").is_file()
    assert len(geofeat.load_features(tmp / "f.HDF5", "frame-001")) > 0


def groundtruth_into_user_folder(tmp):
    _user_files(tmp / "gt" / "seq")
    return _gt(tmp)


def groundtruth_overwrite(tmp):
    seq = _seq(tmp)
    assert main(_gt(tmp, seq=seq)) == 0
    (tmp / "gt" / "seq" / "thesis.txt").write_text("years of work")
    (tmp / "gt" / "seq" / "sub").mkdir()
    (tmp / "gt" / "seq" / "sub" / "notes.md").write_text("notes")
    return _gt(tmp, "--overwrite", seq=seq)


def _gt_files_and_user_files(tmp):
    _user_files_kept(tmp / "gt" / "seq")
    assert (tmp / "gt" / "seq" / "frame-001_theta.npy").is_file()


def _app_with_missing_tps(command: str) -> Callable[[Path], list[str]]:
    def setup(tmp):
        return [command, str(_seq(tmp)), "--descriptors", "sift", "--out", str(tmp / "o"),
                "--tps-dir", str(tmp / "nope")]

    return setup


def nested_tps_folder(tmp):
    """`groundtruth --out gt/seq` nests gt/seq/seq: the bench must take the folder with the files."""
    seq = _seq(tmp)
    assert main(["groundtruth", str(seq), "--out", str(tmp / "gt" / "seq"), "--no-progress", "--no-refine"]) == 0
    return _bench_args(tmp, seq, extra=["--tps-dir", str(tmp / "gt")])


def _bench_scored(tmp):
    import csv

    rows = list(csv.DictReader(open(tmp / "b" / "results.csv")))
    assert len(rows) == 1 and float(rows[0]["ms"]) > 0.3


def _bench_features(edit: Callable[[dict], None], npz: bool = False) -> Callable[[Path], list[str]]:
    """bench --features ext=PATH with the sequence's SIFT features (from `extract`), each frame's arrays
    ({frame: {name: array}}) changed by `edit` and stored as an .h5 file or a folder of .npz files."""
    def setup(tmp):
        import h5py

        seq = _seq(tmp)
        assert main(["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp / "f.h5")]) == 0
        with h5py.File(tmp / "f.h5", "r") as fd:  # float descriptors are stored (D, N), as hloc stores them
            groups = {g: {k: v[()].T if v.attrs.get("layout") == "DxN" else v[()] for k, v in fd[g].items()} for g in fd}
        edit(groups)  # on (N, D) descriptors; written back without the attribute, read as (N, D)
        path = tmp / ("npz" if npz else "ext.h5")
        if npz:
            path.mkdir()
            for g, arrays in groups.items():
                np.savez(path / f"{g}.npz", **arrays)
        else:
            with h5py.File(path, "w") as fd:
                for g, arrays in groups.items():
                    for k, v in arrays.items():
                        fd[f"{g}/{k}"] = v
        return _bench_args(tmp, seq, extra=["--features", f"ext={path}"])

    return setup


def _drop_descriptor_rows(groups):
    groups["frame-001"]["descriptors"] = groups["frame-001"]["descriptors"][:-5]


def _nan_descriptor(groups):
    groups["frame-001"]["descriptors"][3] = np.nan


def _keypoints_off_image(groups):
    groups["frame-001"]["keypoints"][:5] += 1000


def _scores_of_other_length(groups):
    for arrays in groups.values():
        arrays["scores"] = np.linspace(1, 0, len(arrays["keypoints"]) + 3)


def _cosine_metric(groups):
    for arrays in groups.values():
        arrays["metric"] = np.array("cosine")


def _noisy_sift(groups, as_uint8: bool = False):
    """The target's SIFT descriptors with integer noise (so that metrics rank differently), as float32
    or as uint8 with metric 'l2' (SIFT's values are integers 0-255)."""
    d = groups["frame-001"]["descriptors"]
    groups["frame-001"]["descriptors"] = np.clip(d + np.random.default_rng(0).integers(0, 60, d.shape), 0, 255)
    for arrays in groups.values():
        arrays["descriptors"] = arrays["descriptors"].astype(np.uint8 if as_uint8 else np.float32)
        if as_uint8:
            arrays["metric"] = np.array("l2")


def bench_uint8_sift_with_l2_metric(tmp):
    """SIFT's features stored as float32 (tmp/float) and as uint8 with metric 'l2' (tmp) must score alike."""
    assert main(_bench_features(_noisy_sift)(tmp / "float")) == 0
    return _bench_features(lambda groups: _noisy_sift(groups, as_uint8=True), npz=True)(tmp)


def _ext_scores_as_float_sift(tmp):
    import csv

    def ext_ms(path):
        return [r["ms"] for r in csv.DictReader(open(path)) if r["descriptor"] == "ext"]

    assert ext_ms(tmp / "b" / "results.csv") == ext_ms(tmp / "float" / "b" / "results.csv") != ["0.0"]


def bench_landmarks_pair_without_common_ids(tmp):
    seq = make_sequence(tmp / "seq", names=("frame-000-master", "frame-001", "frame-002"))
    ids, xy, vis = read_landmarks(seq / "frame-002.csv")
    write_landmarks(seq / "frame-002.csv", ids + 1000, xy, vis)  # another numbering: no id in common
    return _bench_args(tmp, seq, extra=["--protocol", "landmarks"])


def _pair_without_common_ids_not_scored(tmp):
    import csv

    rows = list(csv.DictReader(open(tmp / "b" / "results.csv")))
    assert [r["target"] for r in rows] == ["frame-001"] and float(rows[0]["ms"]) > 0.5


def _simulate_contact_sheet(name: str) -> Callable[[Path], list[str]]:
    def setup(tmp):
        (tmp / "mine.png").write_text("a file")
        return ["simulate", str(tmp / "out"), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                "--texture", "procedural", "--contact-sheet", str(tmp / name)]

    return setup


def _sheet_kept_nothing_simulated(tmp):
    assert (tmp / "mine.png").read_text() == "a file" and not (tmp / "out").exists()


def _retrieval(tmp, *extra):
    make_sequence(tmp / "ds" / "s1")
    make_sequence(tmp / "ds" / "s2")
    return ["retrieval", str(tmp / "ds"), "--descriptors", "sift", "--keypoints", "200", "--samples", "200",
            "--words", "3", "--rerank", "0", "--out", str(tmp / "r"), *extra]


def retrieval_overwrite_user_file_named_like_a_result(tmp):
    (tmp / "r").mkdir()
    (tmp / "r" / "retrieval.md").write_text("my own notes")
    return _retrieval(tmp, "--overwrite")


def retrieval_samples_without_words(tmp):
    args = _retrieval(tmp, "--samples", "5")
    i = args.index("--words")
    return args[:i] + args[i + 2:]


def _nothing_described(monkeypatch):
    import geofeat.apps.retrieval as retrieval

    def described(*args, **kwargs):
        raise AssertionError("frames were described before the bad option was reported")

    monkeypatch.setattr(retrieval, "describe_datasets", described)


def retrieval_conflicting_classes(tmp):
    (tmp / "classes.csv").write_text("sequence,class\ns1,cloth\ns2,paper\ns2,cloth\n")
    return _retrieval(tmp, "--classes", str(tmp / "classes.csv"))


def _track(tmp, *extra, seq=None):
    return ["track", str(seq or _seq(tmp)), "--descriptors", "sift", "--keypoints", "300", "--refine", "none",
            "--out", str(tmp / "t"), *extra]


def track_overwrite_user_file_in_a_result_folder(tmp):
    (tmp / "t" / "seq" / "sift").mkdir(parents=True)
    (tmp / "t" / "seq" / "sift" / "track.gif").write_text("my own animation")
    return _track(tmp, "--overwrite")


def track_reference_without_depth(tmp):
    seq = _seq(tmp)
    cv2.imwrite(str(seq / "frame-000-master-depth.png"), np.zeros((H, W), np.uint16))
    return _track(tmp, seq=seq)


def _no_training(monkeypatch):
    import geofeat.train.detector as detector

    def trained(*args, **kwargs):
        raise AssertionError("trained before the bad option was reported")

    monkeypatch.setattr(detector, "fit", trained)


def _train_detector(tmp, *extra, val=None):
    sim = tmp / "sim"
    if not sim.is_dir():
        assert main(["simulate", str(sim), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                     "--texture", "procedural"]) == 0
    return ["train-detector", "--data", str(sim), "--val", str(val or sim), "--out", str(tmp / "gk.npz"),
            "--steps", "5", "--keypoints", "50", *extra]


def train_detector_over_user_file(tmp):
    (tmp / "gk.npz").write_text("my own weights")
    return _train_detector(tmp)


# ---------------------------------------------------------------- audit of train
def _no_patches(monkeypatch):
    import geofeat.train.dataset as dataset

    def built(*args, **kwargs):
        raise AssertionError("patches were built before the bad option was reported")

    monkeypatch.setattr(dataset, "build_patch_set", built)


def _train(tmp, *extra, out="w.pt"):
    sim = tmp / "sim"
    if not sim.is_dir():
        assert main(["simulate", str(sim), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                     "--texture", "procedural"]) == 0
    return ["train", "--data", str(sim), "--out", str(tmp / out), "--epochs", "1", "--steps", "2",
            "--batch-size", "8", "--keypoints", "50", *extra]


def train_over_user_file(tmp):
    (tmp / "w.pt").write_text("my own weights")
    return _train(tmp)


def train_resume_corrupt_checkpoint(tmp):
    (tmp / "w.pt.ckpt").write_text("not a checkpoint")
    return _train(tmp, "--resume")


def train_resume_with_other_keypoints(tmp):
    """A resumed run trained on the cached patches of the run it resumes, whatever --data and
    --keypoints it named."""
    assert main(_train(tmp)) == 0
    return _train(tmp, "--resume", "--keypoints", "60")


def _val_sim(tmp, name="val", seed=1, overwrite=False):
    assert main(["simulate", str(tmp / name), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural", "--seed", str(seed)] + ["--overwrite"] * overwrite) == 0
    return str(tmp / name)


def train_resume_with_other_val(tmp):
    """--val was not compared: a resumed run scored its later epochs on other sequences than its
    first ones, and its validation curve joined two measures."""
    assert main(_train(tmp, "--val", _val_sim(tmp, "val-a", 1))) == 0
    return _train(tmp, "--resume", "--val", _val_sim(tmp, "val-b", 2))


def train_resume_with_val_simulated_again(tmp):
    assert main(_train(tmp, "--val", _val_sim(tmp))) == 0
    return _train(tmp, "--resume", "--val", _val_sim(tmp, seed=2, overwrite=True))


def train_resume_with_data_simulated_again(tmp):
    """--data was compared by folder only: a resumed run trained on the cached patches of the frames
    its --data folder held before it was simulated again, the new frames ignored without a word."""
    assert main(_train(tmp)) == 0
    assert main(["simulate", str(tmp / "sim"), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural", "--seed", "3", "--overwrite"]) == 0
    return _train(tmp, "--resume")


def train_resume_with_val_left_out(tmp):
    assert main(_train(tmp, "--val", _val_sim(tmp))) == 0
    return _train(tmp, "--resume")


def train_beside_user_patch_archive(tmp):
    (tmp / "w.pt.patches.npz").write_text("my own archive")
    return _train(tmp)


def _weights_load_back(tmp):
    from geofeat.descriptors.geopatch import load_network

    net, _ = load_network(tmp / "weights")
    assert net.config.channels == (16, 32, 64)
    assert main(["extract", str(tmp / "sim"), "--descriptor", f"geopatch={tmp / 'weights'}", "--keypoints", "50",
                 "--out", str(tmp / "f.h5")]) == 0


def _single_frame_sim(tmp):
    one = tmp / "one"
    assert main(["simulate", str(one), "--frames", "1", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural"]) == 0
    return one


def _no_cuda_and_no_patches(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    _no_patches(monkeypatch)


def _nothing_in_tmp(tmp):
    assert list(tmp.iterdir()) == []


def _nothing_trained(tmp):
    assert sorted(p.name for p in tmp.iterdir()) == ["sim"], sorted(p.name for p in tmp.iterdir())


# ---------------------------------------------------------------- audit of groundtruth
def _gt_three(tmp):
    return make_sequence(tmp / "seq", names=("frame-000-master", "frame-001", "frame-002"))


def groundtruth_target_without_depth(tmp):
    seq = _gt_three(tmp)
    cv2.imwrite(str(seq / "frame-001-depth.png"), np.zeros((H, W), np.uint16))
    return _gt(tmp, seq=seq)


def groundtruth_target_of_another_size(tmp):
    """A target frame at half the reference's size: its landmarks lie on the reference's image."""
    seq = _gt_three(tmp)
    write_frame(seq, "frame-001", np.zeros((H // 2, W // 2, 3), np.uint8), np.ones((H // 2, W // 2)))
    return _gt(tmp, seq=seq)


def _gt_other_frames_written(tmp):
    import csv

    out = tmp / "gt" / "seq"
    assert (out / "frame-002_theta.npy").is_file() and not (out / "frame-001_theta.npy").exists()
    rows = {r["frame"]: r["status"] for r in csv.DictReader(open(out / "report.csv"))}
    assert rows == {"frame-001": "failed", "frame-002": "ok"}


def groundtruth_reference_without_depth(tmp):
    seq = _seq(tmp)
    cv2.imwrite(str(seq / "frame-000-master-depth.png"), np.zeros((H, W), np.uint16))
    return _gt(tmp, seq=seq)


def _groundtruth_second_sequence(breakage: Callable[[Path], None]) -> Callable[[Path], list[str]]:
    """Two sequences, the second one bad: refused before the first is worked on."""
    def setup(tmp):
        make_sequence(tmp / "data" / "a")
        breakage(make_sequence(tmp / "data" / "b", names=("frame-000-master", "frame-001")))
        return ["groundtruth", str(tmp / "data"), "--out", str(tmp / "gt"), "--no-progress", "--no-refine"]

    return setup


def _single_frame(seq: Path) -> None:
    for suffix in ("-rgb.png", "-depth.png", ".csv"):
        (seq / f"frame-001{suffix}").unlink()


def _nothing_in_gt(tmp):
    assert not (tmp / "gt" / "a").exists()


def groundtruth_binary_csv(tmp):
    seq = _seq(tmp)
    (seq / "frame-001.csv").write_bytes(b"\xff\xfe\x00 not text")
    return _gt(tmp, seq=seq)


def bench_timing_json_radius(tmp):
    """`bench --timing` times f(.) at the sequence's radius (geofeat.json), as the scores use it."""
    seq = _seq(tmp)
    (seq / "geofeat.json").write_text(json.dumps({"radius": 0.04}))
    return _bench_args(tmp, seq, extra=["--timing"])


def _record_timing_radius(monkeypatch):
    from geofeat.bench import timing

    monkeypatch.setattr(timing, "timing_table", lambda frame, descriptors, radius, **kw: f"timing at radius {radius:g}\n")


def _timed_at_json_radius(tmp):
    assert (tmp / "b" / "timing.md").read_text() == "timing at radius 0.04\n"


CASES = [
    # data loss (issue)
    Case("simulate-overwrite-user-files", simulate_over_user_files, 2, "did not write",
         lambda t: _user_files_kept(t / "out")),
    Case("simulate-overwrite-sim-plus-user-file", simulate_over_earlier_simulation_plus_user_file, 2,
         "thesis.txt", lambda t: (t / "out" / "thesis.txt").is_file() or pytest.fail("deleted")),
    Case("simulate-overwrite-earlier-sim", simulate_over_earlier_simulation, 0, "", _two_frames_exactly),
    Case("extract-existing-output", extract_over_existing, 2, "exists.*--overwrite", _earlier_h5_kept),
    Case("extract-error-midway-keeps-output", extract_error_midway, 2, "disk full", _no_partial_files,
         _fail_second_save),
    Case("match-into-user-folder", match_into_user_folder, 2, "not empty", lambda t: _user_files_kept(t / "m")),
    Case("match-overwrite-keeps-user-files", match_overwrite_keeps_user_files, 0, "", _matches_and_user_files),
    Case("bench-partial-row-recomputed", bench_partial_row, 0, "dropped", _results_complete),
    Case("bench-ctrl-c-as-systemerror", bench_interrupted, 130, "interrupted", _no_table, _interrupt_in_walk),
    # silently wrong (issue)
    Case("bench-duplicate-sequence-names", bench_duplicate_names, 2, "two sequences are named 'cloth'"),
    Case("bench-tps-dir-missing", bench_missing_tps_dir, 2, "tps-dir: not a directory"),
    Case("bench-tps-folder-without-files", bench_empty_tps_folder, 2, "no TPS files"),
    Case("bench-keypoint-set-with-geokey", bench_keypoint_set_with_geokey, 2, "keypoint-set: chooses among SIFT"),
    Case("extract-keypoint-set-with-geokey", extract_keypoint_set_with_geokey, 2, "keypoint-set: chooses among SIFT"),
    Case("bench-nested-tps-folder", nested_tps_folder, 0, "", _bench_scored),
    Case("extract-honours-json-radius", extract_json_radius, 0, "radius 0.04 m", _same_descriptors_as_explicit_radius),
    Case("match-off-image-landmark", lambda t: _off_image_landmark(t, "match"), 2, "off the 160x120 image"),
    Case("bench-off-image-landmark", lambda t: _off_image_landmark(t, "bench"), 2, "off the 160x120 image"),
    Case("bench-landmarks-off-image-landmark", lambda t: _off_image_landmark(t, "bench-landmarks"), 2,
         "off the 160x120 image"),
    Case("metres-under-mm-scale", metres_under_mm_scale, 2, "median depth 0.002 m.*--depth-scale"),
    Case("normalised-intrinsics", _with_K([[0.8, 0, 0.5], [0, 0.8, 0.5], [0, 0, 1]]), 2, "focal lengths"),
    Case("negative-focal-length", _with_K([[-150, 0, 79.5], [0, 150, 59.5], [0, 0, 1]]), 2, "focal lengths"),
    Case("preflight-is-not-the-reference", preflight_is_not_the_reference, 0, "", _reference_is_frame0),
    Case("groundtruth-negative-margin", lambda t: _gt(t, "--margin", "-5"), 2, "argument --margin: expected a number >= 0"),
    Case("groundtruth-nan-margin", lambda t: _gt(t, "--margin", "nan"), 2, "argument --margin: expected"),  # "margin_px:"
    Case("groundtruth-infinite-depth-margin", lambda t: _gt(t, "--depth-margin", "inf"), 2,
         "argument --depth-margin: expected"),  # it said "depth_margin_m: expected a finite number"
    Case("demo-nan-angle", lambda t: ["demo", "--out", str(t / "d"), "--angle", "nan"], 2,
         "argument --angle: expected a finite number", _nothing_in_tmp),  # "depth: every pixel is 0", a picture written
    Case("groundtruth-object-moves-back", groundtruth_object_moves_back, 0, "", _report_finite_ok),
    Case("retrieval-single-frame", retrieval_single_frame, 2, "reference frames"),
    Case("retrieval-negative-rerank", retrieval_negative_rerank, 2, "rerank: expected"),
    # tracebacks (issue)
    *[Case(f"{c}-out-is-a-file", _out_is_file(c), 2, "taken", _file_kept)
      for c in ("bench", "match", "track", "retrieval", "groundtruth", "extract")],
    Case("truncated-intrinsics-xml", _intrinsics_text('<?xml version="1.0"?>\n<opencv_storage>\n<intrinsics type_id='),
         2, "cannot parse"),
    Case("geofeat-json-list", _config("[0.001]"), 2, "expected a JSON object"),
    Case("groundtruth-huge-spacing", lambda t: [a for a in _gt(t, "--spacing", "100000") if a != "--no-refine"], 2,
         "spacing: 100000 pixels leaves no control-point grid"),  # --no-refine refuses any --spacing
    # robustness (issue)
    Case("extract-frame-without-depth", _no_depth_frame("extract"), 1, "SKIPPED.*frame-001",
         _extract_kept_other_frames),
    Case("extract-npz-overwrite-skipping-a-frame", extract_npz_rerun_skipping_a_frame, 1,
         "SKIPPED.*frame-001.*removed .*f-frame-001.npz: features of an earlier run", _no_stale_npz),
    Case("match-frame-without-depth", _no_depth_frame("match"), 1, "SKIPPED.*frame-001", _match_kept_other_frames),
    Case("retrieval-frame-without-depth", _no_depth_frame("retrieval"), 1, "SKIPPED.*frame-001", _retrieval_written),
    Case("track-frame-without-depth", _no_depth_frame("track"), 1, "SKIPPED.*frame-001",
         lambda t: "SKIPPED frames: frame-001" in (t / "t" / "tracking.md").read_text() or pytest.fail("not named")),
    # more of our own
    Case("geofeat-json-not-json", _config("{depth_scale: 0.001"), 2, "not valid JSON"),
    Case("geofeat-json-negative-depth-scale", _config('{"depth_scale": -0.001}'), 2, "depth_scale"),
    Case("geofeat-json-radius-string", _config('{"radius": "75mm"}'), 2, "radius"),
    Case("geofeat-json-radius-in-mm", _config('{"radius": 75}', "bench"), 2, "radius"),
    Case("geofeat-json-bad-profile", _config('{"depth_profile": "lidar"}'), 2, "depth_profile"),
    Case("radius-zero", lambda t: ["extract", str(_seq(t)), "--radius", "0", "--out", str(t / "f.h5")], 2, "radius"),
    Case("depth-scale-zero", lambda t: ["extract", str(_seq(t)), "--depth-scale", "0", "--out", str(t / "f.h5")], 2,
         "depth.scale"),
    Case("mm-read-as-metres", lambda t: ["extract", str(_seq(t)), "--depth-scale", "1", "--out", str(t / "f.h5")], 2,
         "median depth 1000 m.*--depth-scale"),
    Case("principal-point-outside", _with_K([[150, 0, 400], [0, 150, 59.5], [0, 0, 1]]), 2, "principal point"),
    Case("intrinsics-without-node", _intrinsics_text('<?xml version="1.0"?>\n<opencv_storage>\n</opencv_storage>\n'),
         2, "no 3x3 matrix"),
    Case("intrinsics-nan", _with_K([[np.nan, 0, 79.5], [0, 150, 59.5], [0, 0, 1]]), 2, "finite"),
    Case("landmark-csv-text", _landmark_csv("id,x,y,valid\n0,abc,3,1\n"), 2, "expected numbers"),
    Case("landmark-csv-repeated-ids", _landmark_csv("id,x,y,valid\n0,10,10,1\n0,20,20,1\n"), 2, "repeats ids"),
    Case("landmark-csv-nan-visible", _landmark_csv("id,x,y,valid\n0,nan,10,1\n"), 2, "finite"),
    Case("depth-size-differs", depth_size_differs, 1, "SKIPPED.*frame-001.*differ in size"),
    Case("two-reference-frames", two_references, 2, "several reference frames"),
    Case("depth-8-bit", depth_8bit, 2, "8-bit"),
    Case("corrupt-colour-frame", corrupt_colour_frame, 1, "SKIPPED.*frame-001", _extract_kept_other_frames),
    Case("bench-into-user-folder", bench_into_user_folder, 2, "not empty", lambda t: _user_files_kept(t / "b")),
    Case("bench-overwrite-foreign-results-csv", bench_overwrite_foreign_results_csv, 2, "did not write",
         _foreign_csv_kept),
    Case("bench-unparsable-row-recomputed", bench_unparsable_row, 0, "dropped", _results_complete),
    # audit of bench
    Case("bench-overwrite-keeps-user-config-json", bench_overwrite_user_config_json, 2,
         "config.json, .*which geofeat did not write", _user_config_kept),
    Case("bench-huge-keypoint-budget", bench_huge_keypoint_budget, 0, "", _bench_scored),
    Case("bench-same-folder-twice", bench_same_folder_twice, 0, "", _one_sequence),
    Case("extract-out-under-a-file", extract_out_under_file, 2, "is a file", _file_kept),
    Case("extract-ctrl-c", extract_interrupted, 130, "interrupted", _nothing_written, _interrupt_extract),
    Case("groundtruth-into-user-folder", groundtruth_into_user_folder, 2, "not empty",
         lambda t: _user_files_kept(t / "gt" / "seq")),
    Case("groundtruth-overwrite-keeps-user-files", groundtruth_overwrite, 0, "", _gt_files_and_user_files),
    Case("groundtruth-negative-depth-margin", lambda t: _gt(t, "--depth-margin", "-1"), 2, "argument --depth-margin"),
    Case("groundtruth-nan-spacing", lambda t: _gt(t, "--spacing", "nan"), 2, "argument --spacing: expected a number >= 2"),
    Case("track-tps-dir-missing", _app_with_missing_tps("track"), 2, "tps-dir"),
    Case("bench-features-count-mismatch", _bench_features(_drop_descriptor_rows), 2,
         r"features ext: seq/frame-001 \(.*ext.h5.*\): descriptors: expected first axis"),
    Case("bench-features-nan-descriptors", _bench_features(_nan_descriptor), 2,
         "features ext: seq/frame-001 .*NaN"),
    Case("bench-features-keypoints-off-image", _bench_features(_keypoints_off_image), 2,
         "features ext: seq/frame-001 .*5 keypoint.s. off the 160x120 image"),
    Case("bench-features-scores-length", _bench_features(_scores_of_other_length), 2,
         "features ext: seq/frame-000-master .*scores: expected"),
    Case("bench-features-cosine-metric", _bench_features(_cosine_metric, npz=True), 2,
         r"frame-000-master.npz\): metric: 'cosine'"),
    Case("bench-features-uint8-l2-metric", bench_uint8_sift_with_l2_metric, 0, "", _ext_scores_as_float_sift),
    Case("bench-landmarks-pair-without-common-ids", bench_landmarks_pair_without_common_ids, 0,
         "no landmark id visible in both frame-000-master and frame-002; pair skipped",
         _pair_without_common_ids_not_scored),
    Case("simulate-contact-sheet-exists", _simulate_contact_sheet("mine.png"), 2, "contact-sheet.*exists",
         _sheet_kept_nothing_simulated),
    Case("simulate-contact-sheet-not-an-image", _simulate_contact_sheet("sheet.txt"), 2, "contact-sheet.*png",
         _sheet_kept_nothing_simulated),
    Case("retrieval-tps-dir-missing", _app_with_missing_tps("retrieval"), 2, "tps-dir"),
    # audit of retrieval, track, train-detector
    Case("retrieval-overwrite-keeps-user-file-named-like-a-result", retrieval_overwrite_user_file_named_like_a_result,
         2, "retrieval.md, which geofeat did not write",
         lambda t: (t / "r" / "retrieval.md").read_text() == "my own notes" or pytest.fail("overwritten")),
    Case("track-overwrite-keeps-user-file-in-a-result-folder", track_overwrite_user_file_in_a_result_folder, 2,
         "did not write", lambda t: (t / "t" / "seq" / "sift" / "track.gif").read_text() == "my own animation"
         or pytest.fail("overwritten")),
    Case("retrieval-negative-samples", lambda t: _retrieval(t, "--samples", "-3"), 2, "samples.*expected"),
    Case("retrieval-samples-not-above-words", lambda t: _retrieval(t, "--samples", "3"), 2,
         "--samples: 3 sampled descriptors are too few for --words 3; expected more than 3",
         lambda t: not (t / "r").exists() or pytest.fail("written"), _nothing_described),
    Case("retrieval-samples-not-above-the-smallest-candidate", retrieval_samples_without_words, 2,
         "--samples: 5 sampled descriptors are too few for the smallest --words candidate, 5; expected more than 5",
         None, _nothing_described),
    Case("retrieval-negative-seed", lambda t: _retrieval(t, "--seed", "-1"), 2, "seed: expected"),
    Case("retrieval-conflicting-class-rows", retrieval_conflicting_classes, 2, "'s2' has class 'paper'"),
    Case("track-nan-threshold", lambda t: _track(t, "--threshold", "nan"), 2, "threshold: expected"),
    Case("track-infinite-threshold", lambda t: _track(t, "--threshold", "inf"), 2, "threshold: expected"),
    Case("track-reference-without-depth", track_reference_without_depth, 2,
         "sequence seq: the reference frame frame-000-master cannot be used"),
    Case("train-detector-over-user-file", train_detector_over_user_file, 2, "exists.*--overwrite",
         lambda t: (t / "gk.npz").read_text() == "my own weights" or pytest.fail("overwritten"), _no_training),
    Case("train-detector-zero-keypoints", lambda t: _train_detector(t, "--keypoints", "0"), 2, "argument --keypoints: expected",
         None, _no_training),
    Case("train-detector-zero-steps", lambda t: _train_detector(t, "--steps", "0"), 2, "argument --steps: expected",
         None, _no_training),
    Case("train-detector-zero-width", lambda t: _train_detector(t, "--hidden", "0"), 2, "argument --hidden: expected",
         None, _no_training),
    Case("train-detector-val-without-ground-truth", lambda t: _train_detector(t, val=_seq(t)), 2,
         "val: .*no simulator ground truth", None, _no_training),
    # audit of train
    Case("train-over-user-file", train_over_user_file, 2, "exists.*--overwrite",
         lambda t: (t / "w.pt").read_text() == "my own weights" or pytest.fail("overwritten"), _no_patches),
    Case("train-zero-epochs", lambda t: _train(t, "--epochs", "0"), 2, "argument --epochs: expected", _nothing_trained,
         _no_patches),
    Case("train-zero-steps", lambda t: _train(t, "--steps", "0"), 2, "argument --steps: expected", _nothing_trained,
         _no_patches),
    Case("train-zero-batch-size", lambda t: _train(t, "--batch-size", "0"), 2, "argument --batch-size: expected",
         _nothing_trained, _no_patches),
    Case("train-nan-learning-rate", lambda t: _train(t, "--lr", "nan"), 2, "argument --lr: expected", _nothing_trained,
         _no_patches),
    Case("train-hardest-mining-batch-of-one", lambda t: _train(t, "--mining", "hardest", "--batch-size", "1"), 2,
         "--batch-size: --mining hardest .* at least 2", _nothing_trained, _no_patches),
    Case("train-zero-channels", lambda t: _train(t, "--channels", "16", "0", "64"), 2, "argument --channels: expected",
         _nothing_trained, _no_patches),
    Case("train-detector-negative-seed", lambda t: _train_detector(t, "--seed", "-1"), 2, "argument --seed: expected",
         None, _no_training),
    Case("train-negative-seed", lambda t: _train(t, "--seed", "-1"), 2, "argument --seed: expected", _nothing_trained,
         _no_patches),
    Case("train-out-a-folder", lambda t: (t / "w").mkdir() or _train(t, out="w"), 2, "w is a folder", None,
         _no_patches),
    Case("train-init-missing", lambda t: _train(t, "--init", str(t / "nope.pt")), 2, "no GeoPatch checkpoint",
         _nothing_trained, _no_patches),
    Case("train-val-without-ground-truth", lambda t: _train(t, "--val", str(_seq(t))), 2,
         "--val: .*no simulator ground truth", None, _no_patches),
    Case("train-resume-corrupt-checkpoint", train_resume_corrupt_checkpoint, 2, "resume: .*w.pt.ckpt is not a checkpoint",
         lambda t: not (t / "w.pt").exists() or pytest.fail("trained"), _no_patches),  # reported before the patches
    Case("train-resume-with-other-keypoints", train_resume_with_other_keypoints, 2,
         r"--resume: .*w.pt.patches.npz holds the patches of a run with other options \(--keypoints 50, not 60\)",
         None, _no_patches),
    Case("train-resume-with-other-val", train_resume_with_other_val, 2,
         r"--resume: .*w.pt.patches.npz holds the patches of a run with other options \(--val val-a, not val-b\)",
         None, _no_patches),
    Case("train-resume-with-val-simulated-again", train_resume_with_val_simulated_again, 2,
         r"\(--val val: other frames than that run's \(simulated again or edited since\)\)", None, _no_patches),
    Case("train-resume-with-data-simulated-again", train_resume_with_data_simulated_again, 2,
         r"holds the patches of a run with other options \(--data sim: other frames than that run's \(simulated "
         r"again or edited since\)\)", None, _no_patches),
    Case("train-resume-with-val-left-out", train_resume_with_val_left_out, 2, r"\(--val val, not left out\)",
         None, _no_patches),
    Case("train-beside-user-patch-archive", train_beside_user_patch_archive, 2, "w.pt.patches.npz exists",
         lambda t: (t / "w.pt.patches.npz").read_text() == "my own archive" or pytest.fail("overwritten"),
         _no_patches),
    Case("train-data-without-sequences", lambda t: (t / "empty").mkdir() or _train(t, "--data", str(t / "empty")), 2,
         "--data: no sequence", None, _no_patches),  # it said "dataset: no sequence"
    Case("train-detector-val-without-sequences",
         lambda t: (t / "empty").mkdir() or _train_detector(t, "--val", str(t / "empty")), 2, "--val: no sequence",
         None, _no_training),
    Case("train-out-without-extension", lambda t: _train(t, out="weights"), 0, "wrote .*weights",
         _weights_load_back),  # a RuntimeError traceback ("invalid file name") after the whole training
    Case("train-out-onnx-name", lambda t: _train(t, out="w.ONNX"), 2, "--out: .*w.ONNX: `train` writes PyTorch weights",
         _nothing_trained, _no_patches),  # written, then refused by extract as "not a GeoPatch ONNX model"
    Case("train-device-typo", lambda t: _train(t, "--device", "gpu"), 2, "--device: expected", _nothing_trained,
         _no_patches),  # a torch RuntimeError traceback, after the patches were built
    Case("train-device-cuda-without-gpu", lambda t: _train(t, "--device", "cuda"), 2, "--device.*no CUDA GPU",
         _nothing_trained, _no_cuda_and_no_patches),  # torch's AssertionError, after the patches were built
    Case("train-val-single-frame", lambda t: _train(t, "--val", str(_single_frame_sim(t))), 2,
         "--val: .*one has only its reference frame", None, _no_patches),
    Case("train-detector-val-single-frame", lambda t: _train_detector(t, val=_single_frame_sim(t)), 2,
         "val: .*one has only its reference frame", None, _no_training),  # a TypeError after training
    Case("simulate-huge-width", lambda t: ["simulate", str(t / "out"), "--frames", "2", "--width", "100000",
                                           "--no-progress"], 2, "--width: expected a whole number from 32 to 8192",
         _nothing_in_tmp),
    Case("simulate-negative-seed", lambda t: ["simulate", str(t / "out"), "--frames", "2", "--seed", "-1",
                                              "--no-progress"], 2, "seed: expected", _nothing_in_tmp),
    # audit of groundtruth
    Case("groundtruth-target-without-depth", groundtruth_target_without_depth, 1,
         "FAILED frame frame-001: .*every pixel is 0", _gt_other_frames_written),
    Case("groundtruth-target-of-another-size", groundtruth_target_of_another_size, 1,
         "FAILED frame frame-001: .*80x60.*160x120", _gt_other_frames_written),
    Case("groundtruth-reference-without-depth", groundtruth_reference_without_depth, 2,
         "reference frame frame-000-master cannot be used.*every pixel is 0"),
    Case("groundtruth-second-sequence-single-frame", _groundtruth_second_sequence(_single_frame), 2,
         "sequence b: needs a reference", _nothing_in_gt),
    Case("groundtruth-second-sequence-missing-csv",
         _groundtruth_second_sequence(lambda s: (s / "frame-001.csv").unlink()), 2,
         "sequence b: frame frame-001 has no landmark csv", _nothing_in_gt),
    Case("groundtruth-landmark-csv-not-text", groundtruth_binary_csv, 2, "frame-001.csv: not a text"),
    # audit of extract and match
    Case("extract-frame-of-another-size", _frame_of_another_size("extract"), 1,
         "SKIPPED frame frame-001: .*320x240.*160x120", _extract_kept_other_frames),
    Case("match-frame-of-another-size", _frame_of_another_size("match"), 1,
         "SKIPPED frame frame-001: .*320x240.*160x120", _match_kept_other_frames),
    Case("extract-out-hdf5-in-upper-case", extract_out_in_other_case, 0, "to .*f.HDF5\n",
         _features_file_in_other_case),
    # audit of the docs: the one radius rule in every command
    Case("bench-timing-honours-json-radius", bench_timing_json_radius, 0, "", _timed_at_json_radius,
         _record_timing_radius),
]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case: Case, tmp_path: Path, capsys, monkeypatch) -> None:
    args = case.setup(tmp_path)
    capsys.readouterr()
    if case.patch is not None:
        case.patch(monkeypatch)
    try:
        code = main(args)
        usage = False
    except SystemExit as stop:  # an option argparse refuses: its usage lines, then one error line
        code, usage = stop.code, True
    captured = capsys.readouterr()
    err_lines = [line for line in captured.err.splitlines() if line.strip() and "it/s]" not in line
                 and "%|" not in line and not (usage and line.startswith(("usage:", " ")))]
    assert code == case.code, (code, captured.err[-2000:])
    if case.code == 2:
        assert len(err_lines) == 1 and err_lines[0].startswith(f"geofeat {args[0]}: error: "), captured.err[-2000:]
    if case.message:
        import re

        assert re.search(case.message, captured.out + captured.err, re.S), captured.err[-2000:]
    if case.check is not None:
        case.check(tmp_path)


class _Stop(Exception):
    """Raised by a patched step to end a run once its checks are done."""


def _stop(*args, **kwargs):
    raise _Stop


def test_validation_sequences_that_are_also_training_sequences_are_warned_of(tmp_path, monkeypatch):
    """--val is "held-out": a sequence under --data too (passed twice, or a folder of sequences that
    holds it) inflates the validation score, and train-detector chooses its radius and threshold on it."""
    import geofeat.train.dataset as dataset
    import geofeat.train.detector as detector

    sims = tmp_path / "sims"
    assert main(["simulate", str(sims / "a"), "--frames", "2", "--width", "64", "--height", "48", "--no-progress",
                 "--texture", "procedural"]) == 0
    monkeypatch.setattr(dataset, "build_patch_set", _stop)
    monkeypatch.setattr(detector, "collect", _stop)
    for args in (["train", "--data", str(sims), "--val", str(sims / "a"), "--out", str(tmp_path / "w.pt")],
                 ["train-detector", "--data", str(sims / "a"), "--val", str(sims), "--out", str(tmp_path / "k.npz")]):
        with pytest.warns(UserWarning, match=r"--val: .*a is also under --data.*not held out"), pytest.raises(_Stop):
            main(args)
    assert main(["simulate", str(tmp_path / "val"), "--frames", "2", "--width", "64", "--height", "48",
                 "--no-progress", "--texture", "procedural", "--seed", "1"]) == 0  # seed 0 would repeat sims/a
    with pytest.raises(_Stop), warnings.catch_warnings():  # held-out sequences: no warning
        warnings.filterwarnings("error", message=".*held out")
        main(["train-detector", "--data", str(sims), "--val", str(tmp_path / "val"), "--out", str(tmp_path / "k.npz")])


def test_simulate_and_train_detector_count_in_words(tmp_path, capsys):
    """"wrote 1 frames", "from 1 sequences", and a run that kept no score threshold reported
    "threshold -inf, floor: the best 0 % of each frame's candidates"."""
    assert main(["simulate", str(tmp_path / "one"), "--frames", "1", "--width", "64", "--height", "48",
                 "--no-progress", "--texture", "procedural"]) == 0
    assert f"wrote 1 frame to {tmp_path / 'one'}" in capsys.readouterr().out
    assert main(_train_detector(tmp_path)) == 0
    out = capsys.readouterr().out
    assert "candidates from 1 sequence," in out and "-inf" not in out and "best 0 %" not in out
    import re

    assert re.search(r"(none did, so no score threshold|threshold [0-9.]+, floor: the best [1-9]\d* %)\)", out), out


def test_enough_cases() -> None:
    assert len(CASES) >= 29 + 20


def test_uint16_colour_is_rescaled() -> None:
    image = np.random.default_rng(0).integers(0, 255, (H, W, 3), dtype=np.uint8)
    a = geofeat.RGBDFrame(image, np.ones((H, W)), K)
    b = geofeat.RGBDFrame(image.astype(np.uint16) * 257, np.ones((H, W)), K)
    assert b.image.max() <= 1.0 and np.abs(a.image - b.image).max() < 1e-2
    assert len(geofeat.detect(b, 300)) > 0


@pytest.mark.parametrize("name, expected", [("frame-000-master", True), ("cloud_ref", True), ("Ref.1", True),
                                            ("seq_reference", True), ("ref2", True), ("cloth_preflight", False),
                                            ("refined-03", False), ("mastered", False), ("frame-001", False)])
def test_reference_names_are_whole_tokens(name: str, expected: bool) -> None:
    from geofeat.inputs import is_reference_name

    assert is_reference_name(name) is expected


def test_a_torn_bench_block_is_dropped_whole(tmp_path: Path) -> None:
    """A kill inside the one write of a sequence's rows can leave some of its rows complete and the
    next cut: the whole block is dropped, so the sequence is recomputed in full."""
    from geofeat.bench.runner import COLUMNS, _append_rows, _finished, repair_results

    path = tmp_path / "results.csv"
    path.write_text(",".join(COLUMNS) + "\n")
    row = dict(reference="r", target="t", descriptor="sift", detector="sift", protocol="detect", keypoint_set="p",
               depth_profile="", ms=0.5, mma=0.5, repeatability=0.5, hits=1, n_gt=1, n_ref=1, n_tgt=1,
               seconds_extract=0.1, seconds_match=0.1, angle_deg=0.0, scale=1.0)
    _append_rows(path, [dict(row, sequence="a", target=t) for t in ("t1", "t2")])
    _append_rows(path, [dict(row, sequence="b", target=t) for t in ("t1", "t2")])
    path.write_text(path.read_text()[:-10])  # the second row of b is cut
    assert repair_results(path) == 2  # the cut row and the complete row of b before it
    assert _finished(path) == {("a", "sift")}
    assert path.read_text().endswith("\n")


DATA = Path(geofeat.__file__).parent / "data"


@pytest.mark.parametrize("name, weights, message", [
    ("geopatch", "corrupt.pt", "corrupt.pt is not a GeoPatch checkpoint"),
    ("geopatch", DATA / "logpolar_sim.pt", "logpolar_sim.pt holds logpolar-sim weights .*not GeoPatch; name them "
                                           "logpolar-sim=PATH"),
    ("geopatch", DATA / "geokey.npz", "geokey.npz holds GeoKey detector weights .*--detector geokey=PATH"),
    ("geopatch", "corrupt.onnx", "corrupt.onnx is not a GeoPatch ONNX model"),
    ("tfeat-sim", DATA / "geopatch.pt", "geopatch.pt holds geopatch weights .*not tfeat-sim; name them geopatch=PATH"),
    ("tfeat-sim", DATA / "logpolar_sim.pt", "holds a logpolar-sim network, not tfeat-sim"),
])
def test_descriptor_weights_of_another_network_are_one_error(name: str, weights, message: str, tmp_path: Path) -> None:
    """A corrupt weights file, or one of another network, is a ValueError naming it (no traceback of
    torch or ONNX Runtime, and never a net of the wrong architecture run silently)."""
    if isinstance(weights, str):
        weights = tmp_path / weights
        weights.write_bytes(b"not weights at all")
    frame = geofeat.RGBDFrame(_texture(), np.ones((H, W)), K)
    with pytest.raises(ValueError, match=message):
        geofeat.extract(frame, 10, descriptor=f"{name}={weights}")


def test_train_init_with_geokey_weights_names_the_file_and_what_it_holds(tmp_path: Path, capsys) -> None:
    """`train --init geokey.npz` (a detector's weights for a GeoPatch checkpoint) was refused with torch's
    message inside ("RuntimeError: [enforce fail at inline_container.cc:180] ... not in a subdirectory: mean.npy")."""
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    for weights, holds in ((DATA / "geokey.npz", r"holds GeoKey detector weights \(from `geofeat train-detector`\)"),
                           (tmp_path / "other.npz", r"is a NumPy .npz archive \(arrays a\)")):
        assert main(_train(tmp_path, "--init", str(weights))) == 2
        err = capsys.readouterr().err.strip()
        assert re.fullmatch(f"geofeat train: error: --init: {re.escape(str(weights))} {holds}, not a GeoPatch "
                            "checkpoint of `geofeat train`.*", err), err
        assert "RuntimeError" not in err and ".npy" not in err and len(err.splitlines()) == 1


def _geokey_arrays(**change) -> dict:
    arrays = dict(np.load(DATA / "geokey.npz"))
    arrays.update(change)
    return {k: v for k, v in arrays.items() if v is not None}


@pytest.mark.parametrize("change", [dict(mean=None), dict(mean=np.zeros(3, np.float32)),
                                    dict(w0=np.zeros((5, 4), np.float32), b0=np.zeros(4, np.float32)),
                                    dict(std=np.zeros(13, np.float32)), dict(linear=np.full(8, np.nan, np.float32)),
                                    dict(nms_radius=np.float32(np.nan)), dict(min_fraction=np.float32(2)),
                                    dict(threshold=np.float32(np.nan))],
                         ids=["missing-array", "wrong-shape", "layers-not-ending-in-one-logit", "zero-std",
                              "nan-weights", "nan-radius", "fraction-above-one", "nan-threshold"])
def test_incomplete_geokey_weights_are_one_error(change: dict, tmp_path: Path) -> None:
    path = tmp_path / "gk.npz"
    np.savez(path, **_geokey_arrays(**change))
    with pytest.raises(ValueError, match="gk.npz is not a complete GeoKey weights file"):
        geofeat.detect(geofeat.RGBDFrame(_texture(), np.ones((H, W)), K), 10, detector=f"geokey={path}")


def test_bad_geokey_weights_fail_before_any_frame_is_described(tmp_path: Path, capsys) -> None:
    """Retrieval used to skip every frame with the weights' error and end on "no reference frame";
    the weights are read once, before any work, by the library and by the command line."""
    from geofeat.apps.retrieval import run_retrieval

    make_sequence(tmp_path / "ds" / "s1")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"not weights")
    with pytest.raises(ValueError, match="corrupt.npz is not a GeoKey weights file"):
        run_retrieval([tmp_path / "ds"], tmp_path / "r", ("sift",), detector=f"geokey={corrupt}", progress=False)
    assert not (tmp_path / "r").exists()
    for command in ("retrieval", "track", "extract"):
        with pytest.raises(SystemExit) as stop:
            main([command, str(tmp_path / "ds" / "s1"), "--detector", f"geokey={corrupt}", "--out", str(tmp_path / "o")])
        assert stop.value.code == 2 and "corrupt.npz is not a GeoKey weights file" in capsys.readouterr().err


# ---------------------------------------------------------------- property test of polar_patches
@st.composite
def surfaces(draw):
    """A small frame: a tilted, bumpy surface 0.4-3 m away with random holes, random intrinsics."""
    h = draw(st.integers(24, 56))
    w = draw(st.integers(24, 72))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    f = draw(st.floats(0.4, 3.0)) * max(h, w)
    fy = f * draw(st.floats(0.9, 1.1))
    cx = draw(st.floats(0.2, 0.8)) * (w - 1)
    cy = draw(st.floats(0.2, 0.8)) * (h - 1)
    Km = np.array([[f, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    z0 = draw(st.floats(0.4, 3.0))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    depth = z0 * (1 + draw(st.floats(-0.3, 0.3)) * (xx - cx) / w + 0.05 * np.sin(xx / 3) * np.cos(yy / 4))
    depth *= 1 + rng.normal(0, draw(st.sampled_from([0.0, 0.002, 0.01])), depth.shape)
    holes = rng.random((h, w)) < draw(st.floats(0.0, 0.4))
    if draw(st.booleans()):
        y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
        holes[y0:y0 + h // 3, x0:x0 + w // 3] = True
    depth[holes] = 0
    depth[0, 0] = z0  # at least one valid pixel
    image = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.0)
    n = draw(st.integers(1, 12))
    kps = np.stack([rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n)], 1)
    radius = draw(st.sampled_from([0.01, 0.03, 0.075]))
    profile = draw(st.sampled_from(["clean", "quantised", "kinect"]))
    return geofeat.RGBDFrame(np.clip(image, 0, 1), depth.astype(np.float32), Km), kps, radius, profile


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(surfaces())
def test_polar_patches_valid_ones_lie_on_the_surface(sample) -> None:
    from geofeat.geodesic.polar import polar_patches

    frame, kps, radius, profile = sample
    p = polar_patches(frame, kps, radius=radius, depth_config=profile)
    assert p.valid.shape == (len(kps),) and p.valid.dtype == bool
    v = p.valid
    # valid: finite values in [0, 1], finite coordinates, finite samples in front of the camera
    assert np.isfinite(p.values[v]).all() and (p.values[v] >= 0).all() and (p.values[v] <= 1 + 1e-6).all()
    assert np.isfinite(p.coords[v]).all() and np.isfinite(p.points[v]).all()
    assert (p.points[v][..., 2] > 0).all()
    # ... and on the surface: each sample projects to its image coordinates, at a depth the frame has
    pts = p.points[v].reshape(-1, 3).astype(np.float64)
    proj = np.stack([frame.K[0, 0] * pts[:, 0] / pts[:, 2] + frame.K[0, 2],
                     frame.K[1, 1] * pts[:, 1] / pts[:, 2] + frame.K[1, 2]], 1)
    assert np.abs(proj - p.coords[v].reshape(-1, 2)).max(initial=0) < 0.05
    valid_depth = frame.depth[frame.depth > 0]
    assert (pts[:, 2] >= valid_depth.min() * 0.9).all() and (pts[:, 2] <= valid_depth.max() * 1.1).all()
    # invalid: flagged, never a NaN passed off as data
    assert np.isnan(p.coords[~v]).all() and (p.values[~v] == 0).all()


# --- the output policy itself (geofeat.outputs): links, interrupts, the current folder --------------------------


def test_overwrite_never_deletes_or_writes_through_a_linked_subfolder(tmp_path):
    """A manifest entry (hand-edited, or a result subfolder later replaced by a link) that leads through
    a symbolic link into a folder of the user's: --overwrite removes nothing there, and a result to be
    written there is refused."""
    from geofeat.outputs import MANIFEST, check_out_dir, foreign_clashes, output_folder

    user = tmp_path / "photos"
    user.mkdir()
    (user / "holiday.png").write_bytes(b"mine")
    out = tmp_path / "out"
    out.mkdir()
    (out / "sub").symlink_to(user, target_is_directory=True)
    (out / MANIFEST).write_text(json.dumps({"generator": "geofeat", "files": ["sub/holiday.png"]}))
    check_out_dir(out, overwrite=True)
    with output_folder(out) as tmp:
        (tmp / "result.txt").write_text("new")
    assert (user / "holiday.png").read_bytes() == b"mine"
    assert (out / "result.txt").read_text() == "new"
    assert foreign_clashes(out, ["sub/new.png"]) == ["sub/new.png"]
    with pytest.raises(ValueError, match="did not write"):
        with output_folder(out) as tmp:
            (tmp / "sub").mkdir()
            (tmp / "sub" / "new.png").write_bytes(b"result")
    assert sorted(p.name for p in user.iterdir()) == ["holiday.png"]


@pytest.mark.parametrize("command", [
    ["match", "{seq}", "--descriptor", "orb", "--out", "{seq}"],
    ["track", "{seq}", "--descriptors", "orb", "--out", "{seq}"],
    ["retrieval", "{data}", "--descriptors", "orb", "--out", "{seq}"],
    ["groundtruth", "{seq}", "--no-refine", "--out", "{data}"],  # its result folder is --out/<sequence>
    ["bench", "{seq}", "--descriptors", "orb", "--out", "{seq}"],  # results.csv and tables among the frames
    ["extract", "{seq}", "--descriptor", "orb", "--out", "{seq}"],  # {seq}/features-orb.h5
    ["extract", "{seq}", "--descriptor", "orb", "--out", "{seq}/f.npz"],  # {seq}/f-<frame>.npz beside each frame
], ids=["match", "track", "retrieval", "groundtruth", "bench", "extract-folder", "extract-npz-prefix"])
@pytest.mark.parametrize("overwrite", [False, True])
def test_output_folder_that_is_the_input_sequence_is_refused(tmp_path, capsys, command, overwrite):
    """A sequence geofeat simulated (its files in its manifest) named as the result folder: before,
    --overwrite deleted every frame of it and left only the results (and without it the error advised
    --overwrite). Now one line naming the input, with or without --overwrite, and the sequence intact."""
    from geofeat.outputs import write_manifest

    seq = make_sequence(tmp_path / "data" / "seq")
    write_manifest(seq, [p.name for p in seq.iterdir()])
    before = {p.name: p.read_bytes() for p in seq.iterdir()}
    argv = [a.format(seq=seq, data=seq.parent) for a in command] + ["--overwrite"] * overwrite
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "input folder" in err and "--overwrite to" not in err and len(err.splitlines()) == 1
    assert {p.name: p.read_bytes() for p in seq.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_bench_rerun_into_its_input_sequence_is_refused_and_extract_writes_beside_it(tmp_path, capsys):
    """A bench that wrote into the sequence (before this was refused) is not resumed there; extract's
    .h5 file named inside the sequence is refused too (an output inside an input folder), and a .npz
    prefix beside the sequence folder is written."""
    seq = make_sequence(tmp_path / "data" / "seq")
    (seq / "results.csv").write_text("sequence,descriptor\n")
    assert main(["bench", str(seq), "--descriptors", "orb", "--out", str(seq)]) == 2
    assert "--out: " in capsys.readouterr().err
    assert main(["extract", str(seq), "--descriptor", "orb", "--out", str(seq / "f.h5")]) == 2
    assert f"lies inside the input folder {seq}" in capsys.readouterr().err
    assert main(["extract", str(seq), "--descriptor", "orb", "--out", str(tmp_path / "data" / "seq.npz")]) == 0
    assert not (seq / "f.h5").exists() and (tmp_path / "data" / "seq-frame-001.npz").is_file()


def test_interrupt_while_replacing_a_folder_keeps_the_earlier_result(tmp_path, monkeypatch):
    """Ctrl-C between the moves of replace_folder: the earlier result is back whole, its manifest lists
    it, and no temporary folder is left (before: the earlier files were gone and the new ones half moved)."""
    import os

    from geofeat.outputs import output_folder, read_manifest

    out = tmp_path / "out"
    with output_folder(out) as tmp:
        for name in ("a.txt", "b.txt", "c.txt"):
            (tmp / name).write_text("old")
    (out / "notes.txt").write_text("user")
    real_replace = os.replace
    pressed = []

    def interrupted(src, dst):  # Ctrl-C once, as the new b.txt is moved in
        if Path(src).name == "b.txt" and Path(dst).parent == out and not pressed:
            pressed.append(src)
            raise KeyboardInterrupt
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with output_folder(out) as tmp:
            for name in ("a.txt", "b.txt", "c.txt"):
                (tmp / name).write_text("new")
    assert {p.name: p.read_text() for p in out.glob("*.txt")} == {"a.txt": "old", "b.txt": "old", "c.txt": "old",
                                                                  "notes.txt": "user"}
    assert sorted(read_manifest(out)) == ["a.txt", "b.txt", "c.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    monkeypatch.setattr(os, "replace", real_replace)
    with output_folder(out) as tmp:
        (tmp / "a.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir() if p.name != ".geofeat-manifest.json") == ["a.txt", "notes.txt"]


def test_a_rerun_removes_what_a_killed_run_left_half_written(tmp_path):
    """SIGKILL runs no clean-up: a killed run leaves its temporary folder (and files) beside the output
    in the user's folder; before, every rerun left them there for good. Now the next write of the same
    output removes those of a process no longer running, and nothing else."""
    import os
    import signal
    import subprocess
    import sys

    from geofeat.outputs import atomic_file, output_folder

    out, table = tmp_path / "out", tmp_path / "table.md"
    script = ("import sys, time\nfrom geofeat.outputs import atomic_file, output_folder\n"
              "with output_folder(sys.argv[1]) as tmp, atomic_file(sys.argv[2]) as t:\n"
              "    (tmp / 'track.csv').write_text('half'); t.write_text('half'); print(flush=True); time.sleep(60)\n")
    child = subprocess.Popen([sys.executable, "-c", script, str(out), str(table)], stdout=subprocess.PIPE,
                             env={**os.environ, "PYTHONPATH": str(Path(geofeat.__file__).parents[1])})
    child.stdout.readline()  # both temporaries written
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [f".geofeat-partial-{child.pid}-out", f".geofeat-partial-{child.pid}-table.md"]
    (tmp_path / ".geofeat-partial-1-out").mkdir()  # a running process's (pid 1): perhaps a concurrent run
    (tmp_path / ".geofeat-partial-mine-out").write_text("a user's")
    with output_folder(out) as tmp:
        (tmp / "track.csv").write_text("whole")
    with atomic_file(table) as tmp:
        tmp.write_text("whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".geofeat-partial-1-out", ".geofeat-partial-mine-out",
                                                          "out", "table.md"]


def test_output_folder_may_be_the_current_folder(tmp_path, monkeypatch):
    """`--out .` (the current folder): the result is written beside the user's files, which stay;
    before, a bare ValueError "PosixPath('.') has an empty name"."""
    from geofeat.outputs import check_out_dir, output_folder

    work = tmp_path / "work"
    work.mkdir()
    (work / "data.csv").write_text("mine")
    monkeypatch.chdir(work)
    check_out_dir(".", overwrite=True)
    for text in ("first", "second"):
        with output_folder(".") as tmp:
            (tmp / "result.txt").write_text(text)
    assert (work / "result.txt").read_text() == "second" and (work / "data.csv").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"]


def test_a_dangling_link_at_an_output_file_name_needs_overwrite(tmp_path):
    from geofeat.outputs import check_out_file

    link = tmp_path / "features.h5"
    link.symlink_to(tmp_path / "on-an-unmounted-disk.h5")
    with pytest.raises(ValueError, match="exists.*--overwrite"):
        check_out_file(link)
    assert check_out_file(link, overwrite=True) == link


def test_match_leaves_a_pair_the_landmarks_cannot_map_unjudged(tmp_path, capsys):
    """A target frame with 3 landmarks seen in both it and the reference (the spline needs 4): the
    spline raised inside the loop, and `match` ended with "landmarks: a thin-plate spline needs >= 4
    landmarks ..., got 3", naming no frame, the other pairs' matches and pictures not written."""
    seq = make_sequence(tmp_path / "seq", names=("frame-000-master", "frame-001", "frame-002"))
    ids, xy, visible = read_landmarks(seq / "frame-002.csv")
    write_landmarks(seq / "frame-002.csv", ids, xy, np.arange(len(ids)) < 3)
    out = tmp_path / "m"
    assert main(["match", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert re.search(r"frame-000-master -> frame-001: \d+ matches, \d+ correct", text)
    assert re.search(r"frame-000-master -> frame-002: \d+ matches, not judged \(no ground truth for frame-002: 3 "
                     r"landmarks visible in both", text)
    assert (out / "frame-000-master__frame-002__sift.png").is_file()
    assert len(geofeat.features.list_names(out / "matches-sift.h5")) == 2
