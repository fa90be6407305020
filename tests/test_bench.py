"""`geofeat bench`: the runner on tiny simulated sequences, identical frames, TPS ground truth,
failures, process pool and Dask."""

import csv
import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

import geofeat
from geofeat.bench.runner import COLUMNS, BenchConfig, run_benchmark
from geofeat.groundtruth.sources import GroundTruth
from geofeat.groundtruth.landmarks import landmark_spline
from geofeat.cli import main
from geofeat.sim import simulate_sequence
from surfaces import write_rolled_kinect_sequence

SMALL = dict(width=320, height=240, progress=False)


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    simulate_sequence(root / "seqs" / "a-deform", scenario="deform", n_frames=3, seed=11, **SMALL)
    simulate_sequence(root / "seqs" / "b-rotate", scenario="rotate", n_frames=3, seed=12, **SMALL)
    # identical frames: the target is a byte copy of the reference (ground truth included)
    same = root / "same" / "c-same"
    simulate_sequence(same, scenario="deform", n_frames=1, seed=13, **SMALL)
    for suffix in ("-rgb.png", "-depth.png", "-gt.npz", ".csv"):
        shutil.copy(same / f"frame-000-master{suffix}", same / f"frame-001{suffix}")
    return root


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_runner_rows_and_columns(datasets, tmp_path):
    config = BenchConfig(descriptors=("geobit", "orb"), n_keypoints=300)
    csv_path, failed = run_benchmark(datasets / "seqs", tmp_path, config, progress=False)
    rows = read_rows(csv_path)
    assert not failed
    assert list(rows[0]) == COLUMNS
    assert len(rows) == 2 * 2 * 2  # sequences x targets x descriptors
    for r in rows:
        assert 0 < float(r["ms"]) <= 1 and int(r["hits"]) <= min(int(r["n_ref"]), int(r["n_tgt"]))
    rotate = [r for r in rows if r["sequence"] == "b-rotate"]
    assert all(np.isfinite(float(r["angle_deg"])) for r in rotate)


def test_identical_frames_score_one(datasets, tmp_path):
    """One keypoint per position: a frame against itself scores 1. With the protocol's keypoints a
    position SIFT found with two orientations is two keypoints, only one of which can have a
    ground-truth partner, so the score stays below 1 by the share of such duplicates."""
    config = BenchConfig(descriptors=("geobit", "orb", "sift"), n_keypoints=300, keypoint_set="unique")
    csv_path, _ = run_benchmark(datasets / "same", tmp_path / "unique", config, progress=False)
    for r in read_rows(csv_path):
        assert float(r["ms"]) == pytest.approx(1.0, abs=0.02), r
        assert r["keypoint_set"] == "unique" and r["depth_profile"] in ("kinect", "clean")
    config = BenchConfig(descriptors=("sift",), n_keypoints=300)
    rows = read_rows(run_benchmark(datasets / "same", tmp_path / "protocol", config, progress=False)[0])
    seq = geofeat.read_sequence(next((datasets / "same").iterdir()))
    kps = geofeat.detect(seq.frame(seq.reference), 300, detector="sift", keypoint_set="protocol")
    kps = kps[GroundTruth(seq, None).reference_keep(kps.xy)]  # on the cloth, as the bench keeps them
    duplicates = len(kps) - len(np.unique(np.round(kps.xy, 2), axis=0))
    assert duplicates > 0
    for r in rows:
        # every position scores once at most (its targets claim one reference keypoint), and a
        # position without a twin always scores
        assert r["keypoint_set"] == "protocol" and int(r["n_ref"]) == len(kps)
        assert len(kps) - 2 * duplicates <= int(r["hits"]) <= len(kps) - duplicates, (r, duplicates)


def test_landmark_tps_reproduces_the_exact_ground_truth(datasets):
    seq = geofeat.read_sequence(datasets / "seqs" / "a-deform")
    target = seq.targets[-1]
    ids_r, xy_r, vis_r = seq.landmarks(seq.reference)
    ids_t, xy_t, vis_t = seq.landmarks(target)
    both = vis_r & vis_t
    tps = landmark_spline(xy_t[both], xy_r[both])
    rng = np.random.default_rng(0)
    lo, hi = xy_t[both].min(axis=0), xy_t[both].max(axis=0)
    points = rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), size=(200, 2))
    exact, visible = seq.correspondences(target, seq.reference, points)
    estimate = tps(points)
    ok = visible
    assert ok.sum() > 100
    assert np.median(np.linalg.norm(estimate[ok] - exact[ok], axis=1)) < 1.0


def test_failed_sequence_is_reported_and_the_rest_runs(datasets, tmp_path):
    broken = tmp_path / "data" / "broken"
    broken.mkdir(parents=True)
    (broken / "x-rgb.png").write_bytes(b"not an image")
    shutil.copytree(datasets / "seqs" / "a-deform", tmp_path / "data" / "a-deform")
    csv_path, failed = run_benchmark(tmp_path / "data", tmp_path / "out", BenchConfig(descriptors=("orb",), n_keypoints=200),
                                     progress=False)
    assert failed == ["broken"]
    assert {r["sequence"] for r in read_rows(csv_path)} == {"a-deform"}


def test_process_pool_and_dask_give_the_same_rows(datasets, tmp_path):
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    one = read_rows(run_benchmark(datasets / "seqs", tmp_path / "one", config, progress=False)[0])
    two = read_rows(run_benchmark(datasets / "seqs", tmp_path / "two", config, workers=2, progress=False)[0])
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        dask_rows = read_rows(run_benchmark(datasets / "seqs", tmp_path / "dask", config,
                                            scheduler=cluster.scheduler_address, progress=False)[0])

    def key(rows):
        return sorted((r["sequence"], r["target"], r["hits"], r["n_ref"], r["n_tgt"]) for r in rows)

    assert key(one) == key(two) == key(dask_rows)


def test_bench_command_writes_table_and_plots(datasets, tmp_path, capsys):
    code = main(["bench", str(datasets / "seqs"), "--descriptors", "geobit,orb", "--keypoints", "200",
                 "--out", str(tmp_path)])
    assert code == 0
    assert "| all (2) |" in (tmp_path / "table.md").read_text()
    assert (tmp_path / "ms_vs_rotate.png").exists()
    assert main(["bench", str(datasets / "seqs"), "--descriptors", "nope", "--out", str(tmp_path)]) == 2


def test_landmarks_protocol(datasets, tmp_path):
    config = BenchConfig(descriptors=("geobit", "orb"), protocol="landmarks")
    rows = read_rows(run_benchmark(datasets / "seqs", tmp_path, config, progress=False)[0])
    assert {r["protocol"] for r in rows} == {"landmarks"} and len(rows) == 2 * 2 * 2
    geobit = [float(r["ms"]) for r in rows if r["descriptor"] == "geobit"]
    assert min(geobit) > 0.8  # 100 Harris corners tracked exactly through mild deformation
    # the landmarks are described where they are annotated: table.md names no SIFT keypoint set for them
    from geofeat.bench.report import markdown_table, read_results

    table = markdown_table(read_results(tmp_path / "results.csv"))
    assert "Detector: landmarks." in table and "Keypoints:" not in table


def test_timing_table_names_the_counts_it_used(datasets):
    from geofeat.bench.timing import timing_table

    seq = geofeat.read_sequence(datasets / "seqs" / "a-deform")
    table = timing_table(seq.frame(0), ("geobit", "orb"), 0.075, counts=(50, 100000), repeat=1)
    header = table.splitlines()[0]
    assert "| 50 kps (s) |" in header and "100000" not in header
    assert "geobit matching (N x N)" in table and "map f(.)" in table
    # the mesh's profile, which sets the cost of f(.) (the simulator's clean depth: full resolution)
    assert "depth profile: clean." in table


def test_timing_table_names_what_each_row_leaves_out(datasets):
    """"map f(.)" and "geobit extraction" were timed on a mesh built outside the timing (and
    geobit on patches given), where orb's extraction holds all its work: side by side the
    geodesic descriptors looked cheaper by the mesh and f(.), unsaid. The mesh has a row of its own."""
    from geofeat.bench.timing import timing_table

    seq = geofeat.read_sequence(datasets / "seqs" / "a-deform")
    steps = [line.split(" | ")[0].lstrip("| ") for line in
             timing_table(seq.frame(0), ("geobit", "orb"), 0.075, counts=(50,), repeat=1).splitlines()[2:]
             if line.startswith("| ")]
    assert steps == ["depth mesh (once per frame)", "map f(.) (polar patches, mesh above reused)",
                     "geobit extraction (patches given: mesh and f(.) above)", "geobit matching (N x N)",
                     "orb extraction", "orb matching (N x N)"]


def test_rerun_skips_finished_results_and_refuses_other_settings(datasets, tmp_path, monkeypatch):
    from geofeat.bench import runner

    calls = []
    real = runner.evaluate_sequence
    monkeypatch.setattr(runner, "evaluate_sequence", lambda f, c, d=None: calls.append((f, d)) or real(f, c, d))
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    csv_path, _ = run_benchmark(datasets / "seqs", tmp_path, config, progress=False)
    first = read_rows(csv_path)
    assert len(calls) == 2 and len(first) == 4
    run_benchmark(datasets / "seqs", tmp_path, config, progress=False)
    assert len(calls) == 2 and read_rows(csv_path) == first  # nothing redone, nothing lost
    # a new descriptor: only it is computed, the finished ones are kept
    config = BenchConfig(descriptors=("orb", "sift"), n_keypoints=200)
    run_benchmark(datasets / "seqs", tmp_path, config, progress=False)
    assert [d for _, d in calls[2:]] == [("sift",), ("sift",)]
    assert len(read_rows(csv_path)) == 8
    with pytest.raises(ValueError, match="other settings") as refused:
        run_benchmark(datasets / "seqs", tmp_path, BenchConfig(descriptors=("orb",), n_keypoints=100), progress=False)
    # the message names what differs (not every setting of the earlier run, to be compared by eye)
    assert "n_keypoints 200 there, 100 now" in str(refused.value) and "tps_dir" not in str(refused.value)
    run_benchmark(datasets / "seqs", tmp_path, BenchConfig(descriptors=("orb",), n_keypoints=100), progress=False,
                  overwrite=True)
    assert len(read_rows(csv_path)) == 4


def test_a_rerun_naming_the_default_depth_profile_auto_resumes(datasets, tmp_path, monkeypatch):
    """A rerun naming `--depth-profile auto` was refused as 'other settings (depth_profile null there,
    "auto" now)'. The default (None: geofeat.json's profile, else measured) and "auto" (measured)
    choose the same profile on these simulated sequences, so it resumes; the refusal message names
    an unset profile in words, not as null."""
    from geofeat.bench import runner

    calls = []
    real = runner.evaluate_sequence
    monkeypatch.setattr(runner, "evaluate_sequence", lambda f, c, d=None: calls.append(d) or real(f, c, d))
    csv_path, _ = run_benchmark(datasets / "seqs", tmp_path / "a", BenchConfig(descriptors=("orb",), n_keypoints=200),
                                progress=False)
    rows = read_rows(csv_path)
    run_benchmark(datasets / "seqs", tmp_path / "a", BenchConfig(descriptors=("orb",), n_keypoints=200,
                                                                 depth_profile="auto"), progress=False)
    assert len(calls) == 2 and read_rows(csv_path) == rows  # resumed: nothing redone
    run_benchmark(datasets / "seqs", tmp_path / "b", BenchConfig(descriptors=("orb",), n_keypoints=200,
                                                                 depth_profile="auto"), progress=False)
    run_benchmark(datasets / "seqs", tmp_path / "b", BenchConfig(descriptors=("orb",), n_keypoints=200), progress=False)
    assert len(calls) == 4
    # a profile named: another run. A resumed run's config.json holds its own settings: "auto" in a, the default in b
    with pytest.raises(ValueError, match="depth_profile auto there, kinect now") as refused:
        run_benchmark(datasets / "seqs", tmp_path / "a", BenchConfig(descriptors=("orb",), n_keypoints=200,
                                                                     depth_profile="kinect"), progress=False)
    assert '"' not in str(refused.value)  # names read as words, not as JSON
    with pytest.raises(ValueError, match=r"depth_profile the default \(geofeat.json's, else auto\) there, kinect now"):
        run_benchmark(datasets / "seqs", tmp_path / "b", BenchConfig(descriptors=("orb",), n_keypoints=200,
                                                                     depth_profile="kinect"), progress=False)


def test_rerun_refuses_weights_retrained_at_the_same_path(datasets, tmp_path):
    """A rerun into the same folder resumes; with the detector's weights file rewritten since (same
    path, same settings), its new rows would be mixed with the old ones under one name."""
    import dataclasses

    from geofeat.detectors.geokey import load_geokey

    weights = tmp_path / "w.npz"
    shipped = load_geokey()
    shipped.save(weights)
    config = BenchConfig(descriptors=("orb",), detector=f"geokey={weights}", n_keypoints=200)
    out = tmp_path / "out"
    csv_path, _ = run_benchmark(datasets / "seqs", out, config, progress=False)
    rows = read_rows(csv_path)
    run_benchmark(datasets / "seqs", out, config, progress=False)  # unchanged weights: resumed, nothing redone
    assert read_rows(csv_path) == rows
    dataclasses.replace(shipped, linear=shipped.linear * 1.5).save(weights)  # "retrained"
    with pytest.raises(ValueError, match="other weights at the same path.*detector"):
        run_benchmark(datasets / "seqs", out, config, progress=False)
    run_benchmark(datasets / "seqs", out, config, progress=False, overwrite=True)


def test_a_rerun_refuses_another_sequence_of_a_finished_ones_name(datasets, tmp_path):
    """Results are keyed by the sequence name: before, a rerun on another folder named like a finished
    sequence skipped it and reported the first folder's numbers for it. Now refused by name; a
    rerun on the same folders, through a link or with more sequences, still resumes."""
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    out = tmp_path / "out"
    csv_path, _ = run_benchmark(datasets / "seqs" / "a-deform", out, config, progress=False)
    rows = read_rows(csv_path)
    link = tmp_path / "link"
    link.symlink_to(datasets / "seqs", target_is_directory=True)
    run_benchmark(link, out, config, progress=False)  # the same a-deform, and b-rotate added
    assert read_rows(csv_path)[:len(rows)] == rows and {r["sequence"] for r in read_rows(csv_path)} == {"a-deform",
                                                                                                       "b-rotate"}
    other = tmp_path / "elsewhere" / "a-deform"
    shutil.copytree(datasets / "same" / "c-same", other)
    with pytest.raises(ValueError, match=f"another sequence of the same name.*a-deform read from .*seqs/a-deform there, "
                                         f"from {other} now"):
        run_benchmark(other, out, config, progress=False)
    run_benchmark(other, out, config, progress=False, overwrite=True)
    # the copy of identical frames: one target (the deformed a-deform had two)
    assert [(r["sequence"], r["target"]) for r in read_rows(csv_path)] == [("a-deform", "frame-001")]


def _benched_copy(datasets, tmp_path, config):
    """A copy of the sequence a-deform in tmp_path/seqs, benched into tmp_path/out: (its folder, the
    run's results.csv, its rows)."""
    seq = tmp_path / "seqs" / "a-deform"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    csv_path, _ = run_benchmark(seq, tmp_path / "out", config, progress=False)
    return seq, csv_path, read_rows(csv_path)


def test_a_rerun_refuses_a_finished_sequence_whose_frames_were_replaced(datasets, tmp_path):
    """Before, a rerun checked settings, weights and the folder's path, not its files: a sequence
    re-simulated or re-annotated in place kept its old rows, mixed with new sequences' ones. Now the
    files' digest is compared; touching the files (same contents) still resumes."""
    import os

    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    seq, csv_path, rows = _benched_copy(datasets, tmp_path, config)
    out = tmp_path / "out"
    for f in seq.iterdir():  # same contents, new times: resumed, nothing recomputed
        os.utime(f, ns=(f.stat().st_atime_ns, f.stat().st_mtime_ns + 10**9))
    run_benchmark(seq, out, config, progress=False)
    assert read_rows(csv_path) == rows
    target = sorted(seq.glob("*-rgb.png"))[-1]
    image = cv2.imread(str(target))
    cv2.imwrite(str(target), np.ascontiguousarray(image[::-1]))  # the frame replaced in place
    with pytest.raises(ValueError, match="holds results of a-deform, whose files changed since"):
        run_benchmark(seq, out, config, progress=False)
    run_benchmark(seq, out, config, progress=False, overwrite=True)


def test_a_rerun_refuses_a_finished_sequence_whose_groundtruth_json_changed(datasets, tmp_path):
    """groundtruth.json (the cloth's grid spacing the exact correspondences are computed with) was not
    in the sequence's digest: with it edited in place, a rerun into the same --out kept the rows scored
    against the old ground truth without a word. Now refused by name."""
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    seq, csv_path, rows = _benched_copy(datasets, tmp_path, config)
    meta = json.loads((seq / "groundtruth.json").read_text())
    (seq / "groundtruth.json").write_text(json.dumps(dict(meta, spacing_m=meta["spacing_m"] * 1.1)))
    with pytest.raises(ValueError, match="holds results of a-deform, whose files changed since.*groundtruth.json"):
        run_benchmark(seq, tmp_path / "out", config, progress=False)
    assert read_rows(csv_path) == rows
    fresh, _ = run_benchmark(seq, tmp_path / "fresh", config, progress=False)
    assert [r["n_tgt"] for r in read_rows(fresh)] != [r["n_tgt"] for r in rows]  # other ground truth, other rows


def test_a_rerun_of_a_run_whose_digests_left_out_groundtruth_json_resumes_and_says_so(datasets, tmp_path):
    """config.json written before groundtruth.json was in the digest: the rerun compares the rest of
    the files (a frame replaced is still refused), keeps the finished rows with a warning that names
    the unchecked file and --overwrite, and records the whole digest for the next rerun."""
    from geofeat.io import sequence_digest

    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    seq, csv_path, rows = _benched_copy(datasets, tmp_path, config)
    out = tmp_path / "out"
    settings = json.loads((out / "config.json").read_text())
    older = dict(settings, sequence_digests={"a-deform": sequence_digest(seq)})  # the older rule's digest
    (out / "config.json").write_text(json.dumps(older))
    with pytest.warns(UserWarning, match="older geofeat.*left out groundtruth.json.*a-deform are kept.*--overwrite"):
        run_benchmark(seq, out, config, progress=False)
    assert read_rows(csv_path) == rows
    assert json.loads((out / "config.json").read_text())["sequence_digests"] == settings["sequence_digests"]
    (out / "config.json").write_text(json.dumps(older))
    target = sorted(seq.glob("*-rgb.png"))[-1]
    cv2.imwrite(str(target), np.ascontiguousarray(cv2.imread(str(target))[::-1]))
    with pytest.raises(ValueError, match="holds results of a-deform, whose files changed since"):
        run_benchmark(seq, out, config, progress=False)


def test_sequence_digest_follows_the_files_a_reader_uses(datasets, tmp_path):
    from geofeat.io import sequence_digest

    seq = tmp_path / "s"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    before = sequence_digest(seq)
    assert sequence_digest(datasets / "seqs" / "a-deform") == before  # a copy: the same
    (seq / "notes.txt").write_text("not read by geofeat")
    (seq / ".DS_Store").write_bytes(b"x")
    assert sequence_digest(seq) == before
    (seq / "intrinsics.xml").write_text((seq / "intrinsics.xml").read_text() + "\n")
    assert sequence_digest(seq) != before


def test_features_written_by_extract_as_npz_are_scored_as_the_h5(datasets, tmp_path, capsys):
    """`geofeat extract --out DIR/f.npz` writes DIR/f-<frame>.npz; `bench --features m=DIR/f.npz` now
    reads them (before: "does not exist", and a folder of them: no <frame>.npz), with the same scores as
    the .h5 that extract writes for the same frames."""
    seq = datasets / "seqs" / "a-deform"
    for out in ("f.npz", "f.h5"):
        assert main(["extract", str(seq), "--descriptor", "sift", "--keypoints", "200", "--out", str(tmp_path / out)]) == 0
    assert sorted(p.name for p in tmp_path.glob("f-*.npz")) == [f"f-{n}.npz" for n in geofeat.read_sequence(seq).names]
    scores = {}
    for out in ("f.npz", "f.h5"):
        bench_out = tmp_path / f"bench-{out}"
        assert main(["bench", str(seq), "--descriptors", "orb", "--keypoints", "200", "--features",
                     f"mine={tmp_path / out}", "--out", str(bench_out)]) == 0
        scores[out] = [(r["target"], r["ms"]) for r in read_rows(bench_out / "results.csv") if r["descriptor"] == "mine"]
    assert len(scores["f.npz"]) == 2 and scores["f.npz"] == scores["f.h5"]
    # a stem nothing was written under: refused, naming the layout looked for
    assert main(["bench", str(seq), "--descriptors", "orb", "--features", f"mine={tmp_path / 'g.npz'}", "--out",
                 str(tmp_path / "b3")]) == 2
    assert "nor any g-<frame>.npz beside it" in capsys.readouterr().err


def test_changed_weights_compares_only_what_both_runs_recorded():
    from geofeat.bench.runner import _changed_weights

    before = {"detector_weights_sha256": "a", "descriptor_weights_sha256": {"geopatch=w.pt": "x", "geopatch=v.pt": None}}
    assert _changed_weights(before, before) == []
    assert _changed_weights(before, {"detector_weights_sha256": "b"}) == ["the detector's"]
    now = {"detector_weights_sha256": "a", "descriptor_weights_sha256": {"geopatch=w.pt": "y", "geopatch=v.pt": "z",
                                                                        "geopatch=new.pt": "n"}}
    assert _changed_weights(before, now) == ["'geopatch=w.pt'"]  # an unknown old hash and a new name: not compared
    assert _changed_weights({}, now) == []  # a config.json written before the hashes were recorded


def test_match_command_counts_the_bench_hits(datasets, tmp_path, capsys):
    """`geofeat match` judges matches with the bench's ground truth: on the same keypoints and
    matches it counts exactly the benchmark's hits."""
    from geofeat.groundtruth.sources import GroundTruth, correct_matches
    from geofeat.scoring import ground_truth_pairs, score_detect

    seq = geofeat.read_sequence(datasets / "seqs" / "a-deform")
    ref, target = seq.frame(seq.reference), seq.targets[-1]
    tgt = seq.frame(target)
    d = geofeat.make_descriptor("orb")
    k_ref, k_tgt = geofeat.detect(ref, 300, detector="sift"), geofeat.detect(tgt, 300, detector="sift")
    m = geofeat.match(d.compute(ref, k_ref), d.compute(tgt, k_tgt))
    truth = GroundTruth(seq, None)
    correct = correct_matches(truth, target, k_ref.xy, k_tgt.xy, m.matches0)
    mapped = truth.map(target, k_tgt.xy)[0]
    hits = score_detect(m.matches0, ground_truth_pairs(k_ref.xy, mapped), len(k_ref), len(k_tgt)).hits
    assert correct.sum() == hits > 20
    assert main(["match", str(seq.folder), "--descriptor", "orb", "--keypoints", "300", "--out", str(tmp_path)]) == 0
    assert f"-> {target}: {(m.matches0 >= 0).sum()} matches, {hits} correct" in capsys.readouterr().out


def test_bad_descriptor_names_fail_before_anything_is_built(tmp_path):
    with pytest.raises(ValueError, match="unknown name 'surf'"):
        BenchConfig(descriptors=("orb", "surf"))
    with pytest.raises(ValueError, match="no weights file"):
        BenchConfig(descriptors=(f"geopatch={tmp_path / 'missing.pt'}",))
    with pytest.raises(ValueError, match="keypoint_set"):
        BenchConfig(keypoint_set="all")


def test_sequences_are_grouped_by_their_scenario_word():
    from geofeat.bench.report import sequence_group

    assert [sequence_group(n) for n in ("deform-0", "b-rotate", "hard_scale_2", "cloud-roll", "seq")] == \
        ["deform", "rotate", "scale", "roll", "all"]


def test_curves_have_one_line_per_detector_and_descriptor(tmp_path):
    from geofeat.bench.report import CURVES, curve_series, plot_curves

    rows = [{"sequence": f"rotate-{k}", "descriptor": desc, "detector": det, "angle_deg": angle,
             "scale": float("nan"), "ms": ms}
            for k in range(2) for det, base in (("sift", 0.2), ("geokey", 0.4)) for desc in ("geopatch", "geobit")
            for angle, ms in ((10.0, base), (90.0, base / 2))]
    key, kind, _, bins = CURVES[0]
    series = curve_series(rows, key, kind, bins)
    assert set(series) == {"sift + geopatch", "sift + geobit", "geokey + geopatch", "geokey + geobit"}
    x, y = series["geokey + geopatch"]
    np.testing.assert_allclose(x, [10.0, 90.0])
    np.testing.assert_allclose(y, [0.4, 0.2])
    one = curve_series([r for r in rows if r["detector"] == "sift"], key, kind, bins)
    assert set(one) == {"geopatch", "geobit"}
    assert [p.name for p in plot_curves(rows, tmp_path)] == ["ms_vs_rotate.png"]
    assert not [p.name for p in tmp_path.iterdir() if p.name != "ms_vs_rotate.png"]  # no partial file left


def test_curve_titles_name_the_keypoints_and_what_the_points_average():
    """With one detector the legend names only the descriptors: the plot said nowhere whose keypoints
    (SIFT's, GeoKey's, the landmarks) the MS was measured on, nor over how many sequences."""
    from geofeat.bench.report import curve_title

    rows = [{"sequence": f"rotate-{k}", "reference": "r", "target": t, "descriptor": d, "detector": "geokey"}
            for k in range(2) for t in ("a", "b", "c") for d in ("geopatch", "sift")]
    assert curve_title(rows, "rotate") == "MS on 2 rotate sequences, 6 pairs; keypoints: geokey"
    rows[0]["detector"] = "sift"  # several: the legend names them
    assert curve_title(rows, "rotate") == "MS on 2 rotate sequences, 6 pairs"


def test_curve_titles_count_only_the_pairs_the_curve_draws():
    """A pair without a camera roll (NaN: a real sequence named "rotate", no simulator pose) is not
    drawn (`curve_series` keeps finite x only), but the title counted it: "2 rotate sequences, 4
    pairs" over points that average 1 sequence and 2 pairs."""
    from geofeat.bench.report import CURVES, curve_series, curve_title

    rows = [{"sequence": seq, "reference": "r", "target": t, "descriptor": "orb", "detector": "sift",
             "angle_deg": angle, "ms": 0.5} for seq, angle in (("sim-rotate", 30.0), ("real-rotate", float("nan")))
            for t in ("a", "b")]
    key, kind, _, bins = CURVES[0]
    assert len(curve_series(rows, key, kind, bins)["orb"][0]) == 1  # both drawn pairs in one bin
    assert curve_title(rows, kind, key=key) == "MS on 1 rotate sequence, 2 pairs (2 without a camera roll left out); keypoints: sift"


def test_detail_table_gives_the_denominator_of_ms():
    """The protocol's denominator min(n_ref, n_tgt) must be readable from details.md: two detectors
    with the same hits differ in MS only through the target keypoints the protocol keeps."""
    from geofeat.bench.report import detail_table

    row = dict(descriptor="geopatch", detector="geokey", sequence="a-deform", ms=0.4, mma=0.8,
               repeatability=0.5, n_ref=1000, n_tgt=800, hits=320)
    table = detail_table([row, dict(row, n_tgt=600, ms=320 / 600)])
    header, _, first, total = table.strip().splitlines()[:4]
    assert "target keypoints kept / pair" in header
    cells = [c.strip() for c in first.split("|")[1:-1]]
    assert cells[6:9] == ["1000", "700", "320"]  # per-sequence means: n_ref, n_tgt, hits


def test_a_descriptor_named_twice_is_refused(datasets, tmp_path):
    """"orb,ORB" (or "orb,orb") used to write every orb row two times into results.csv."""
    with pytest.raises(ValueError, match="'orb' is named twice"):
        BenchConfig(descriptors=("orb", "ORB"))
    assert main(["bench", str(datasets / "seqs"), "--descriptors", "orb,sift,orb", "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b").exists()


def _without_ground_truth(npz):
    """The simulator's ground truth of a frame that shows no cloth (every pixel background)."""
    arrays = dict(np.load(npz))
    arrays["uv"][:] = -1
    np.savez(npz, **arrays)


def test_a_target_without_ground_truth_is_skipped_not_scored_zero(datasets, tmp_path, capsys):
    """A target frame where the ground truth covers no pixel keeps no keypoint: it used to be scored
    MS = MMA = 0 and averaged into its sequence's mean."""
    seq = tmp_path / "data" / "a-deform"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    _without_ground_truth(seq / "frame-002-gt.npz")
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    csv_path, failed = run_benchmark(tmp_path / "data", tmp_path / "out", config, progress=False)
    rows = read_rows(csv_path)
    assert not failed and [r["target"] for r in rows] == ["frame-001"] and float(rows[0]["ms"]) > 0
    assert "a-deform: the ground truth covers no pixel of frame-002; pair skipped" in capsys.readouterr().out


def test_table_and_details_name_the_pairs_the_run_skipped(datasets, tmp_path, capsys):
    """A skipped pair was said only in the run's scrolled output (not again when resumed): table.md
    and details.md averaged a sequence's pairs with one fewer, unsaid."""
    seq = tmp_path / "data" / "a-deform"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    _without_ground_truth(seq / "frame-002-gt.npz")
    assert main(["bench", str(tmp_path / "data"), "--descriptors", "orb", "--keypoints", "200",
                 "--out", str(tmp_path / "out")]) == 0
    note = "Not scored, so in no mean above: 1 pair (skipped by the run, which said why): a-deform/frame-002."
    assert note in (tmp_path / "out" / "table.md").read_text()
    assert note in (tmp_path / "out" / "details.md").read_text()


def test_unscored_pairs_note_names_the_descriptors_a_pair_lacks():
    from geofeat.bench.report import unscored_pairs_note

    rows = [dict(sequence="s", target=t, descriptor=d) for t, d in (("f1", "orb"), ("f1", "ext"), ("f2", "orb"))]
    assert unscored_pairs_note(rows, {"s": ["f1", "f2", "f3"], "other": ["f1"]}).strip() == (
        "Not scored, so in no mean above: 2 pairs (skipped by the run, which said why): s/f2 (ext), s/f3.")
    assert unscored_pairs_note(rows[:1], {"s": ["f1"]}) == ""


def test_external_features_skip_a_target_without_ground_truth_too(datasets, tmp_path, capsys):
    """`--features` scores its pairs with the same rule: a target the ground truth does not cover is
    skipped by name, not scored 0."""
    import geofeat
    from geofeat.io import read_sequence

    seq = tmp_path / "data" / "a-deform"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    _without_ground_truth(seq / "frame-002-gt.npz")
    s = read_sequence(seq)
    (tmp_path / "feats").mkdir()
    for name in s.names:
        frame = s.frame(name)
        f = geofeat.make_descriptor("orb").compute(frame, geofeat.detect(frame, 200, detector="sift"))
        np.savez(tmp_path / "feats" / f"{name}.npz", keypoints=f.keypoints[f.valid], descriptors=f.descriptors[f.valid])
    config = BenchConfig(descriptors=(), features=(f"mine={tmp_path / 'feats'}",), n_keypoints=200)
    csv_path, failed = run_benchmark(tmp_path / "data", tmp_path / "out", config, progress=False)
    rows = read_rows(csv_path)
    assert not failed and [r["target"] for r in rows] == ["frame-001"] and float(rows[0]["ms"]) > 0
    assert "a-deform: the ground truth covers no pixel of frame-002; pair skipped for mine" in capsys.readouterr().out


def test_a_reference_without_ground_truth_fails_its_sequence(datasets, tmp_path, capsys):
    """No reference keypoint on the object by the ground truth: every pair used to score 0."""
    seq = tmp_path / "data" / "a-deform"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    _without_ground_truth(seq / "frame-000-master-gt.npz")
    shutil.copytree(datasets / "seqs" / "b-rotate", tmp_path / "data" / "b-rotate")
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    csv_path, failed = run_benchmark(tmp_path / "data", tmp_path / "out", config, progress=False)
    assert failed == ["a-deform"] and {r["sequence"] for r in read_rows(csv_path)} == {"b-rotate"}
    assert "covers no pixel of the reference frame frame-000-master" in capsys.readouterr().out


def test_overwrite_leaves_no_report_of_the_earlier_run(datasets, tmp_path):
    """details.md (protocol detect only) of an earlier run used to stay beside the new table.md."""
    out = tmp_path / "b"
    args = ["bench", str(datasets / "seqs" / "a-deform"), "--descriptors", "orb", "--keypoints", "200",
            "--out", str(out)]
    assert main(args) == 0 and (out / "details.md").is_file()
    (out / "notes.md").write_text("mine")
    assert main(args + ["--protocol", "landmarks", "--overwrite"]) == 0
    assert not (out / "details.md").exists() and (out / "notes.md").read_text() == "mine"
    assert "landmarks" in read_rows(out / "results.csv")[0]["protocol"]


def test_a_rerun_never_replaces_a_report_name_the_user_wrote_beside_the_results(datasets, tmp_path, capsys):
    """A resumed (or --overwrite) run skipped the output-folder check that a first run makes, and wrote
    timing.md (or table.md, a curve) over the user's file of that name, which geofeat did not write."""
    out = tmp_path / "b"
    args = ["bench", str(datasets / "seqs" / "a-deform"), "--descriptors", "orb", "--keypoints", "200",
            "--out", str(out)]
    assert main(args) == 0 and not (out / "timing.md").exists()
    (out / "timing.md").write_text("mine")
    for again in ([], ["--overwrite"]):
        assert main(args + ["--timing"] + again) == 2
        assert "timing.md" in capsys.readouterr().err
        assert (out / "timing.md").read_text() == "mine"


def test_landmarks_protocol_says_which_detection_options_it_does_not_use(datasets, tmp_path, capsys):
    """--protocol landmarks describes the annotated landmarks: a --keypoints or --detector given
    with it changes nothing, and the command says so instead of ignoring them silently."""
    args = ["bench", str(datasets / "seqs" / "a-deform"), "--descriptors", "orb", "--protocol", "landmarks"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert "not used" not in capsys.readouterr().out
    assert main(args + ["--keypoints", "300", "--detector", "geokey", "--out", str(tmp_path / "b")]) == 0
    assert "--keypoints, --detector not used" in capsys.readouterr().out
    def scores(folder):
        return [{k: v for k, v in r.items() if not k.startswith("seconds")} for r in read_rows(folder / "results.csv")]

    assert scores(tmp_path / "a") == scores(tmp_path / "b")


def test_landmarks_protocol_names_detection_options_given_at_their_default_values(datasets, tmp_path, capsys):
    """docs/cli.md: --keypoints, --detector and --keypoint-set do not apply to --protocol landmarks, and
    the command says so when they are given: also when given at bench's defaults (2048, sift), which
    were silently ignored."""
    args = ["bench", str(datasets / "seqs" / "a-deform"), "--descriptors", "orb", "--protocol", "landmarks",
            "--keypoints", "2048", "--detector", "sift", "--out", str(tmp_path / "a")]
    assert main(args) == 0
    assert "--keypoints, --detector not used" in capsys.readouterr().out


def test_curves_take_sequences_by_their_scenario_word():
    """"grayscale-deform" is no scale sequence (the table groups it under deform); it used to be
    drawn in the scale curve because "scale" is in its name."""
    from geofeat.bench.report import CURVES, curve_series

    rows = [{"sequence": seq, "descriptor": "orb", "detector": "sift", "angle_deg": 0.0, "scale": scale, "ms": ms}
            for seq, scale, ms in (("b-scale", 0.5, 0.2), ("grayscale-deform", 0.99, 0.9), ("hard_scale_2", 0.6, 0.4))]
    key, kind, _, bins = CURVES[1]
    x, y = curve_series(rows, key, kind, bins)["orb"]
    np.testing.assert_allclose(x, [0.5, 0.6])
    np.testing.assert_allclose(y, [0.2, 0.4])


def test_table_says_when_a_descriptor_has_fewer_sequences():
    """A rerun can add a descriptor on other sequences than the earlier ones (other datasets, a
    failure): its mean is over fewer sequences, which the table must say rather than set side by side."""
    from geofeat.bench.report import markdown_table

    rows = [dict(sequence=s, descriptor=d, ms=ms, mma=ms) for s, d, ms in
            (("a-deform", "orb", 0.2), ("b-deform", "orb", 0.6), ("b-deform", "sift", 0.5))]
    lines = markdown_table(rows).splitlines()
    assert lines[2] == "| deform (2) | **0.400** | 0.500 (1 of 2) |"
    assert lines[3] == "| all (2) | **0.400** | 0.500 (1 of 2) |"


def test_table_bolds_no_mean_over_fewer_sequences_than_its_row():
    """sift has a result on b-deform only, where orb scores more (0.6 against 0.5); its mean over
    that one sequence, 0.500, was bold as the row's best beside orb's 0.400 over both. A cell over
    fewer sequences is not compared: the best is of the cells over all of them, and none when no
    cell covers them all."""
    from geofeat.bench.report import markdown_table

    rows = [dict(sequence=s, descriptor=d, ms=ms, mma=ms) for s, d, ms in
            (("a-deform", "orb", 0.2), ("b-deform", "orb", 0.6), ("b-deform", "sift", 0.5))]
    assert markdown_table(rows).splitlines()[3] == "| all (2) | **0.400** | 0.500 (1 of 2) |"
    rows = [dict(sequence=s, descriptor=d, ms=ms, mma=ms) for s, d, ms in
            (("a-deform", "orb", 0.2), ("b-deform", "sift", 0.5))]
    assert markdown_table(rows).splitlines()[3] == "| all (2) | 0.200 (1 of 2) | 0.500 (1 of 2) |"


def test_simulated_sequences_are_grouped_by_the_scenario_they_were_simulated_with(tmp_path):
    """A simulated roll saved as `cloth1` (no scenario word in its name) is a rotate sequence: the
    table groups it so and the roll curve is drawn (both read only the folder name before)."""
    simulate_sequence(tmp_path / "data" / "cloth1", scenario="rotate", n_frames=3, seed=12, **SMALL)
    out = tmp_path / "out"
    assert main(["bench", str(tmp_path / "data"), "--descriptors", "geobit", "--keypoints", "200",
                 "--out", str(out)]) == 0
    assert "| rotate (1) |" in (out / "table.md").read_text()
    assert (out / "ms_vs_rotate.png").is_file()


def test_table_says_when_an_oriented_descriptor_was_given_upright_keypoints():
    """SIFT's descriptor on GeoKey's keypoints (no orientation) scored near 0 on rolls with only a
    warning inside the progress bar; the table must say why."""
    from geofeat.bench.report import markdown_table

    rows = [dict(sequence="a-rotate", descriptor=d, detector="geokey", ms=ms, mma=ms)
            for d, ms in (("sift", 0.01), ("geopatch", 0.5))]
    assert "sift on GeoKey's keypoints: described upright" in markdown_table(rows)
    assert "upright" not in markdown_table([dict(r, detector="sift") for r in rows])


def _kinect_pair_naming(folder, profile):
    """The shipped Kinect frame and its copy rolled by 20 degrees, with landmarks (a thin-plate
    spline ground truth); geofeat.json names `profile` although the depth measures as kinect."""
    folder.mkdir(parents=True)
    write_rolled_kinect_sequence(folder, 20.0)
    (folder / "geofeat.json").write_text(json.dumps({"depth_profile": profile}))
    return folder


def test_a_rerun_is_another_run_where_auto_and_geofeat_json_choose_other_profiles(tmp_path, monkeypatch):
    """`--depth-profile auto` now measures even where geofeat.json names a profile, so on a sequence
    whose geofeat.json says clean but whose depth measures as kinect, the default and "auto" are
    other runs. A config.json written before that change says "auto" for the geofeat.json rule: the
    profile each finished sequence was described with decides, so it resumes with the default."""
    from geofeat.bench import runner

    calls = []
    real = runner.evaluate_sequence
    monkeypatch.setattr(runner, "evaluate_sequence", lambda f, c, d=None: calls.append(d) or real(f, c, d))
    seq = _kinect_pair_naming(tmp_path / "data" / "cloud", "clean")
    out = tmp_path / "out"
    csv_path, _ = run_benchmark(seq, out, BenchConfig(descriptors=("orb",), n_keypoints=100), progress=False)
    rows = read_rows(csv_path)
    assert {r["depth_profile"] for r in rows} == {"clean"} and len(calls) == 1
    with pytest.raises(ValueError, match=r"depth_profile the default \(geofeat.json's, else auto\) there, auto now: "
                                         "cloud was described with clean, now it would be with kinect"):
        run_benchmark(seq, out, BenchConfig(descriptors=("orb",), n_keypoints=100, depth_profile="auto"), progress=False)
    # an older config.json: "auto" then meant the geofeat.json rule, as the rows recorded
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps(dict(config, depth_profile="auto")))
    run_benchmark(seq, out, BenchConfig(descriptors=("orb",), n_keypoints=100), progress=False)
    assert len(calls) == 1 and read_rows(csv_path) == rows  # resumed: nothing redone
    (out / "config.json").write_text(json.dumps(dict(config, depth_profile="auto")))
    with pytest.raises(ValueError, match="depth_profile auto there, auto now: cloud was described with clean"):
        run_benchmark(seq, out, BenchConfig(descriptors=("orb",), n_keypoints=100, depth_profile="auto"), progress=False)


def test_report_counts_read_as_words():
    """"clean (1 sequences)" in table.md's depth-profile note."""
    from geofeat.bench.report import markdown_table
    from geofeat.outputs import plural

    assert (plural(1, "sequence"), plural(2, "sequence"), plural(0, "class", "classes")) == (
        "1 sequence", "2 sequences", "0 classes")
    row = dict(sequence="a-deform", descriptor="orb", detector="sift", protocol="detect", keypoint_set="protocol",
               depth_profile="clean", ms=0.5, mma=0.5)
    table = markdown_table([row, dict(row, sequence="b-deform", depth_profile="kinect"), dict(row, sequence="c-deform")])
    assert "Depth profile: clean (2 sequences), kinect (1 sequence)." in table


def test_table_bolds_every_cell_that_prints_the_best_value():
    """Bold went to the larger unrounded mean only: 0.4144 and 0.4141 both print as 0.414, and only
    one of the two equal numbers was marked best."""
    from geofeat.bench.report import markdown_table

    rows = [dict(sequence="a-deform", descriptor=d, ms=ms, mma=ms) for d, ms in
            (("geobit", 0.4141), ("geopatch", 0.4144), ("sift", 0.3))]
    assert markdown_table(rows).splitlines()[2] == "| deform (1) | **0.414** | **0.414** | 0.300 |"


def test_detail_table_names_the_keypoints_it_counts():
    """The column "keypoints / frame" is the mean of n_ref, the reference frame's keypoints kept on
    the object: with --keypoints 300 it read 254 beside 269 target keypoints, as if each frame had 254."""
    from geofeat.bench.report import detail_table

    rows = [dict(descriptor="sift", detector="sift", sequence="a", ms=0.1, mma=0.2, repeatability=0.3,
                 n_ref=254, n_tgt=n_tgt, hits=10) for n_tgt in (285, 236)]
    header, _, first = detail_table(rows).splitlines()[:3]
    columns = [c.strip() for c in header.split("|")[1:-1]]
    cells = dict(zip(columns, (c.strip() for c in first.split("|")[1:-1])))
    assert cells["reference keypoints / frame"] == f"{np.mean([r['n_ref'] for r in rows]):.0f}"
    assert cells["target keypoints kept / pair"] == f"{np.mean([r['n_tgt'] for r in rows]):.0f}"


def test_report_keeps_one_descriptor_on_two_detectors_apart():
    """benchmarks/merge_bench.py merges a `--detector geokey` and a `--detector sift` run of the same
    descriptors (BENCHMARKS.md, docs/detector.md): summary, table.md and details.md averaged the two
    detectors' pairs into one "geopatch" (0.4 here, a figure neither run had)."""
    from geofeat.bench.report import detail_table, markdown_table, summary

    row = dict(sequence="a-deform", reference="ref", target="t1", descriptor="geopatch", protocol="detect",
               keypoint_set="unique", depth_profile="clean", mma=0.9, repeatability=0.7, hits=300, n_gt=400,
               n_ref=1000, n_tgt=1000)
    rows = [dict(row, detector="geokey", ms=0.6), dict(row, detector="geokey", sequence="b-rotate", ms=0.6),
            dict(row, detector="sift", ms=0.2), dict(row, detector="sift", sequence="b-rotate", ms=0.2),
            dict(row, descriptor="geobit", detector="geokey", ms=0.5)]
    s = summary(rows)
    assert {k: v["ms"] for k, v in s.items()} == {"geokey + geopatch": 0.6, "sift + geopatch": 0.2, "geobit": 0.5}
    table = markdown_table(rows)
    assert table.splitlines()[0] == "| sequences | geokey + geopatch | sift + geopatch | geobit |"
    assert "0.400" not in table
    details = [line for line in detail_table(rows).splitlines() if "**all**" in line]
    assert [line.split(" | ")[:4] for line in details] == [["| geopatch", "geokey", "**all**", "0.600"],
                                                           ["| geopatch", "sift", "**all**", "0.200"],
                                                           ["| geobit", "geokey", "**all**", "0.500"]]


def test_sequences_of_one_frame_only_are_one_error_before_anything_is_written(tmp_path):
    """A folder whose every sequence has a single frame (the shipped Kinect frame) cannot be scored:
    one error naming them, and no config.json or header-only results.csv left behind."""
    seq = tmp_path / "data" / "bag"
    shutil.copytree(geofeat.io.demo_data_dir(), seq)
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="no sequence has a reference and a target frame.*bag"):
        run_benchmark([str(tmp_path / "data")], out, BenchConfig(descriptors=("geobit",)), progress=False)
    assert not out.exists()


def test_a_rerun_refuses_features_rewritten_at_the_same_path(datasets, tmp_path):
    """`--features NAME=PATH` rewritten in place since a run (the user's export fixed, another method
    saved over it): a rerun into the same --out used to skip the finished sequence and keep the old
    file's scores under the name. Features added for another sequence leave the finished one's alone."""
    import h5py

    seqs = datasets / "seqs"
    path = tmp_path / "mine.h5"

    def write(sequence, shift=0.0):
        s = geofeat.read_sequence(seqs / sequence)
        with h5py.File(path, "a") as fd:
            for name in s.names:
                frame = s.frame(name)
                f = geofeat.make_descriptor("orb").compute(frame, geofeat.detect(frame, 200, detector="sift"))
                if f"{sequence}/{name}" in fd:
                    del fd[f"{sequence}/{name}"]
                g = fd.create_group(f"{sequence}/{name}")
                g["keypoints"] = np.clip(f.keypoints[f.valid] + shift, 0, 230)
                g["descriptors"] = f.descriptors[f.valid]

    write("a-deform")
    config = BenchConfig(descriptors=(), features=(f"mine={path}",), n_keypoints=200)
    csv_path, failed = run_benchmark(seqs / "a-deform", tmp_path / "out", config, progress=False)
    before = read_rows(csv_path)
    assert not failed and len(before) == 2 and all(float(r["ms"]) > 0 for r in before)
    # unchanged, and another sequence's groups added: the finished rows are kept, the new sequence scored
    write("b-rotate")
    csv_path, failed = run_benchmark(seqs, tmp_path / "out", config, progress=False)
    rows = read_rows(csv_path)
    assert not failed and rows[:2] == before and {r["sequence"] for r in rows[2:]} == {"b-rotate"}
    # a-deform's features rewritten (shifted 5 px): they score otherwise, and the rerun says so
    write("a-deform", shift=5.0)
    fresh, _ = run_benchmark(seqs / "a-deform", tmp_path / "fresh", config, progress=False)
    assert [r["ms"] for r in read_rows(fresh)] != [r["ms"] for r in before]
    with pytest.raises(ValueError, match="--features mine of a-deform, whose files changed since"):
        run_benchmark(seqs, tmp_path / "out", config, progress=False)


def test_paired_ms_difference_averages_and_resamples_by_sequence():
    """benchmarks/walk_interpolated_rays.py's paired difference: the bench's mean over sequences of
    per-sequence means, and a bootstrap interval over sequences (the pairs of one sequence share its
    reference keypoints). Here one sequence of 30 pairs changes by +0.01 each, another of 10 by -0.01:
    the sequences disagree, so the interval must span both; resampling the 40 pairs gave
    +0.005 [+0.0025, +0.0075], a confident gain, where the bench's mean is 0."""
    from benchmark_scripts import import_benchmarks

    walk_interpolated_rays, common = import_benchmarks("walk_interpolated_rays", "common")
    paired_ms_line, paired_by_sequence = walk_interpolated_rays.paired_ms_line, common.paired_by_sequence
    keys = [("a", "ref", f"t{i}", "geopatch") for i in range(30)] + [("b", "ref", f"t{i}", "geopatch") for i in range(10)]
    walked = np.full(40, 0.5)
    interpolated = walked + np.r_[np.full(30, 0.01), np.full(10, -0.01)]
    p = paired_by_sequence(keys, walked, interpolated)
    assert p["diff"] == pytest.approx(0.0) and (p["sequences"], p["pairs"]) == (2, 40)
    assert p["low"] == pytest.approx(-0.01) and p["high"] == pytest.approx(0.01)
    runs = {"walked": dict(zip(keys, walked)), "interpolated": dict(zip(keys, interpolated))}
    assert "+0.0000 [-0.0100, +0.0100] (95 % bootstrap over 2 sequences, 40 pairs)" in paired_ms_line(runs, "geopatch")


def test_other_processes_cpu_leaves_out_this_process(tmp_path):
    """bench_pipeline.py's idle check (`common.others_cores`): the machine's busy CPU from /proc/stat
    less this process's own CPU over the block's wall time. The busy time is the cpu line's user,
    nice, system, irq, softirq and steal ticks (not idle or iowait); subtracting this process's own
    is what leaves the others; and without /proc/stat the figure is NaN, never a false 'idle'."""
    from benchmark_scripts import import_benchmarks

    common = import_benchmarks("common")[0]
    busy_cpu_seconds, others_cores = common.busy_cpu_seconds, common.others_cores
    stat = tmp_path / "stat"
    # user nice system idle iowait irq softirq steal guest guest_nice, in clock ticks
    stat.write_text("cpu  100 20 30 5000 400 5 6 7 0 0\ncpu0 50 10 15 2500 200 2 3 3 0 0\n")
    assert busy_cpu_seconds(str(stat)) == pytest.approx(168 / os.sysconf("SC_CLK_TCK"))
    assert busy_cpu_seconds(str(tmp_path / "absent")) is None
    assert others_cores(10.0, 11.0, 0.5, 1.0) == pytest.approx(0.5)  # one busy second, half of it ours
    assert others_cores(10.0, 10.4, 0.5, 1.0) == 0.0  # tick rounding never gives a negative share
    assert np.isnan(others_cores(None, 5.0, 0.1, 1.0))


def test_a_target_with_too_few_landmarks_for_the_spline_is_skipped_not_its_sequence(datasets, tmp_path, capsys):
    """Ground truth from the csv landmarks (no simulator files): a target frame with fewer than 4
    landmarks visible in both frames has no spline. It failed the whole sequence (every other pair
    lost too) with a message that named no frame; it is skipped by name, as a target the TPS files
    leave out."""
    seq = tmp_path / "data" / "a-deform"
    seq.mkdir(parents=True)
    for path in (datasets / "seqs" / "a-deform").iterdir():
        if not path.name.endswith("-gt.npz") and path.name != "groundtruth.json":
            shutil.copy(path, seq / path.name)
    lines = (seq / "frame-002.csv").read_text().splitlines()
    hidden = [lines[0]] + [",".join(line.split(",")[:3] + ["1" if i < 2 else "0"]) for i, line in enumerate(lines[1:])]
    (seq / "frame-002.csv").write_text("\n".join(hidden) + "\n")
    config = BenchConfig(descriptors=("orb",), n_keypoints=200)
    csv_path, failed = run_benchmark(tmp_path / "data", tmp_path / "out", config, progress=False)
    rows = read_rows(csv_path)
    assert not failed and [r["target"] for r in rows] == ["frame-001"] and float(rows[0]["ms"]) > 0
    out = capsys.readouterr().out
    assert "a-deform: no ground truth for frame-002" in out and "pair skipped" in out


@pytest.mark.parametrize("lost", ["frame-002-gt.npz", "groundtruth.json"])
def test_a_simulated_sequence_missing_a_ground_truth_file_fails_by_name(datasets, tmp_path, capsys, lost):
    """One <frame>-gt.npz (or groundtruth.json) missing from a simulated sequence: every pair of the
    sequence was scored with the csv landmarks' spline instead of the exact ground truth (other
    reference keypoints kept, another MS) without a word. It fails by name; with none of the
    simulator's files the landmarks score it, as before (see the test above)."""
    seq = tmp_path / "data" / "a-deform"
    shutil.copytree(datasets / "seqs" / "a-deform", seq)
    (seq / lost).unlink()
    csv_path, failed = run_benchmark(tmp_path / "data", tmp_path / "out", BenchConfig(descriptors=("orb",), n_keypoints=200),
                                     progress=False)
    assert failed == ["a-deform"] and read_rows(csv_path) == []
    out = capsys.readouterr().out
    assert "the simulator's ground truth is incomplete" in out and f"missing {lost}" in out


def test_a_rerun_refuses_rows_scored_with_tps_files_made_again_since(datasets, tmp_path):
    """The TPS ground truth was compared by its --tps-dir text only: `geofeat groundtruth` run again
    into the same folder (other splines) and a bench rerun into the same --out kept the old rows beside
    the new ones, scored against other ground truth, without a word."""
    from geofeat.cli import main

    seqs = tmp_path / "seqs"
    shutil.copytree(datasets / "seqs" / "a-deform", seqs / "a-deform")
    tps = tmp_path / "tps"
    assert main(["groundtruth", str(seqs), "--out", str(tps), "--no-refine", "--no-progress"]) == 0
    config = BenchConfig(descriptors=("orb",), n_keypoints=200, tps_dir=str(tps))
    csv_path, failed = run_benchmark(seqs, tmp_path / "out", config, progress=False)
    rows = read_rows(csv_path)
    assert not failed and len(rows) == 2
    run_benchmark(seqs, tmp_path / "out", config, progress=False)  # unchanged: resumed, nothing redone
    assert read_rows(csv_path) == rows
    theta = tps / "a-deform" / "frame-001_theta.npy"
    np.save(theta, np.load(theta) * 1.01)
    with pytest.raises(ValueError, match="its TPS files made again"):
        run_benchmark(seqs, tmp_path / "out", config, progress=False)
    assert read_rows(csv_path) == rows


def test_merge_bench_refuses_runs_of_other_keypoint_counts(tmp_path, capsys, monkeypatch):
    """benchmarks/merge_bench.py averaged runs made at --keypoints 1024 and 2048 into one column (0.4
    here, a figure neither run had): results.csv has no keypoint-count column. The config.json that
    each run wrote beside its results.csv tells; other counts (or keypoint sets on one detector) are
    refused naming the runs and their values, and runs of one count still merge."""
    from pathlib import Path

    from benchmark_scripts import import_benchmarks

    merge_bench = import_benchmarks("merge_bench")[0]
    row = dict(sequence="a-deform", reference="ref", target="t1", descriptor="geopatch", detector="sift",
               protocol="detect", keypoint_set="protocol", depth_profile="clean", mma=0.9, repeatability=0.7,
               hits=300, n_gt=400, n_ref=1000, n_tgt=1000, seconds_extract=0.0, seconds_match=0.0,
               angle_deg=float("nan"), scale=float("nan"))

    def run(name, n_keypoints, ms, **settings):
        folder = tmp_path / name
        folder.mkdir()
        with open(folder / "results.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, COLUMNS)
            writer.writeheader()
            landmarks = settings.get("protocol") == "landmarks"
            writer.writerow(dict(row, ms=ms, **(dict(protocol="landmarks", detector="landmarks") if landmarks else {})))
        config = dict(protocol="detect", detector="sift", keypoint_set="protocol", n_keypoints=n_keypoints)
        (folder / "config.json").write_text(json.dumps({**config, **settings}))
        return str(folder / "results.csv")

    small, large = run("k1024", 1024, 0.6), run("k2048", 2048, 0.2)
    def merge(*results):  # the command line, as the script is run
        monkeypatch.setattr("sys.argv", ["merge_bench.py", *results, "--out", str(tmp_path / "merged")])
        merge_bench.main()

    with pytest.raises(SystemExit):
        merge(small, large)
    err = capsys.readouterr().err
    assert f"{small} 1024 keypoints" in err and f"{large} 2048 keypoints" in err and "different --keypoints" in err
    assert not (tmp_path / "merged" / "table.md").exists()
    unique = run("unique", 1024, 0.5, keypoint_set="unique")
    with pytest.raises(ValueError, match=f"detector sift with different --keypoint-set.*{small} protocol, {unique} unique"):
        merge_bench.check_mergeable([Path(small), Path(unique)])
    landmarks = run("landmarks", 2048, 0.3, protocol="landmarks")  # describes the landmarks: no keypoint count
    other = run("other", 1024, 0.4)
    merge(small, other, landmarks)
    table = (tmp_path / "merged" / "table.md").read_text()
    assert table.splitlines()[0] == "| sequences | sift + geopatch | landmarks + geopatch |"
    assert "| all (1) | **0.500** | 0.300 |" in table
    on_gpu = run("on_gpu", 1024, 0.5, device="cuda:0")  # a run of `geofeat bench --device cuda:0`
    with pytest.raises(ValueError, match=f"different devices .*{small} cpu, {on_gpu} cuda:0"):
        merge_bench.check_mergeable([Path(small), Path(on_gpu)])
    (tmp_path / "other" / "config.json").unlink()
    with pytest.raises(ValueError, match="cannot read .*other/config.json.*keypoint count is unknown"):
        merge_bench.check_mergeable([Path(small), Path(other)])


def test_tps_files_without_some_ssim_maps_are_refused_and_without_any_said(datasets, tmp_path, capsys):
    """--tps-dir: a target frame without its <k>_SSIM.png was scored without the SSIM filter (the
    protocol's step 3) while the others had it, without a word. Some maps missing: the sequence fails
    naming them. None there: scored by the object masks alone, with one warning for the sequence and
    a note in table.md and details.md."""
    seqs = tmp_path / "seqs"
    shutil.copytree(datasets / "seqs" / "a-deform", seqs / "a-deform")
    tps = tmp_path / "tps"
    assert main(["groundtruth", str(seqs), "--out", str(tps), "--no-refine", "--no-progress"]) == 0
    (tps / "a-deform" / "frame-002_SSIM.png").unlink()
    config = BenchConfig(descriptors=("orb",), n_keypoints=200, tps_dir=str(tps))
    capsys.readouterr()
    csv_path, failed = run_benchmark(seqs, tmp_path / "some", config, progress=False)
    assert failed == ["a-deform"] and read_rows(csv_path) == []
    assert "SSIM map (<k>_SSIM.png, the protocol's step 3) for 1 of the 2 target frames of a-deform with a spline, " \
           "not frame-002_SSIM.png" in capsys.readouterr().out
    (tps / "a-deform" / "frame-001_SSIM.png").unlink()
    with pytest.warns(UserWarning, match="no SSIM map .* for any target frame of a-deform: step 3 .* skipped") as said:
        assert main(["bench", str(seqs), "--descriptors", "orb", "--keypoints", "200", "--tps-dir", str(tps),
                     "--out", str(tmp_path / "none")]) == 0
    assert len([w for w in said if "SSIM" in str(w.message)]) == 1
    assert len(read_rows(tmp_path / "none" / "results.csv")) == 2
    for report in ("table.md", "details.md"):
        assert "SSIM filter (protocol step 3) skipped for a-deform" in (tmp_path / "none" / report).read_text()


def test_first_run_benchmark_runs_the_readme_example_as_written(tmp_path):
    """benchmarks/bench_first_run.py --job readme times the README's Python example: the script it
    writes must be that example (the block under "In Python"), with only the .h5 file it saves moved
    into the benchmark's own folder, so that timing it writes nothing into the working directory."""
    from benchmark_scripts import import_benchmarks

    bench_first_run = import_benchmarks("bench_first_run")[0]
    script = bench_first_run.readme_example(tmp_path).read_text()
    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    assert script.replace(repr(str(tmp_path / "frame.h5")), '"frame.h5"') in readme
    assert "geofeat.extract(" in script and repr(str(tmp_path / "frame.h5")) in script
    compile(script, "readme_example.py", "exec")


def test_a_one_time_cost_of_the_first_description_is_in_no_pairs_extraction_time(datasets, monkeypatch):
    """The reference is described once and its time counts in each pair of its sequence, so a
    one-time cost of a process's first description (numba compiling GeoBit's kernels: a minute on
    a fresh install) was in seconds_extract of every pair of the first sequence. A Describer whose
    first call reports 100 s more stands for it here."""
    from geofeat.bench import runner

    class FirstCallCosts(runner.Describer):
        def __call__(self, frame, kps):
            first = not getattr(self, "called", False)
            self.called = True
            return {n: (f, s + (100.0 if first else 0.0)) for n, (f, s) in super().__call__(frame, kps).items()}

    monkeypatch.setattr(runner, "Describer", FirstCallCosts)
    rows = runner.evaluate_sequence(datasets / "seqs" / "b-rotate", BenchConfig(descriptors=("orb",), n_keypoints=100))
    assert len(rows) == 2
    assert all(r["seconds_extract"] < 100.0 for r in rows), [r["seconds_extract"] for r in rows]


@pytest.mark.parametrize("workers", [100000, 0, 2.5])
def test_run_benchmark_refuses_a_worker_count_before_any_process_or_file(tmp_path, capsys, workers):
    """`run_benchmark(workers=100000)` spawned processes until the machine ran out of memory (the CLI's
    --workers had a lower bound only, the Python argument none)."""
    with pytest.raises(ValueError, match=r"^workers: "):
        run_benchmark(tmp_path / "nowhere", tmp_path / "out", BenchConfig(descriptors=("orb",)), workers=workers,
                      progress=False)
    assert not (tmp_path / "out").exists()
    code = main(["bench", str(tmp_path / "nowhere"), "--descriptors", "orb", "--out", str(tmp_path / "out"),
                 "--workers", "100000"])
    assert code == 2 and not (tmp_path / "out").exists()
    assert "workers: 100000 worker processes is far more" in capsys.readouterr().err
