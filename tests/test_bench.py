"""`geofeat bench`: the runner on tiny simulated sequences, identical frames, TPS ground truth,
failures, process pool and Dask."""

import csv
import shutil

import numpy as np
import pytest

import geofeat
from geofeat.bench.protocol import LandmarkTPS
from geofeat.bench.runner import COLUMNS, BenchConfig, run_benchmark
from geofeat.cli import main
from geofeat.sim import simulate_sequence

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
    config = BenchConfig(descriptors=("geobit", "orb", "sift"), n_keypoints=300)
    csv_path, _ = run_benchmark(datasets / "same", tmp_path, config, progress=False)
    for r in read_rows(csv_path):
        assert float(r["ms"]) == pytest.approx(1.0, abs=0.02), r


def test_landmark_tps_reproduces_the_exact_ground_truth(datasets):
    seq = geofeat.read_sequence(datasets / "seqs" / "a-deform")
    target = seq.targets[-1]
    ids_r, xy_r, vis_r = seq.landmarks(seq.reference)
    ids_t, xy_t, vis_t = seq.landmarks(target)
    both = vis_r & vis_t
    tps = LandmarkTPS(xy_t[both], xy_r[both])
    rng = np.random.default_rng(0)
    lo, hi = xy_t[both].min(axis=0), xy_t[both].max(axis=0)
    points = rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), size=(200, 2))
    exact, visible = seq.correspondences(target, seq.reference, points)
    estimate = tps(points)
    ok = visible & np.isfinite(estimate).all(axis=1)
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


def test_timing_table_names_the_counts_it_used(datasets):
    from geofeat.bench.report import timing_table

    seq = geofeat.read_sequence(datasets / "seqs" / "a-deform")
    table = timing_table(seq.frame(0), ("geobit", "orb"), 0.075, counts=(50, 100000), repeat=1)
    header = table.splitlines()[0]
    assert "| 50 kps (s) |" in header and "100000" not in header
    assert "geobit matching (N x N)" in table and "map f(.)" in table
