"""`--device` of `bench`, `track` and `retrieval` (and `device=` of their functions): GeoPatch described
and matched on the GPU path, the other descriptors on the CPU, the device in bench's results, and the
refusals of extract's `--device`.

Without a GPU the GPU calls are stood in for by the CPU's (`fake_gpu`): what is checked is that the
device reaches the description (`compute_cuda`) and the matching (`geofeat.match(..., device=)`), and
that nothing does without it. The GPU path itself runs in numba's CUDA simulator
(`test_describer_on_the_gpu_path_in_cuda_simulator`) and, on a GPU, in tests/test_gpu.py."""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import pytest
import torch
from cuda_simulator import SMALL_FRAME, run_simulated

import geofeat.bench.runner
import geofeat.bench.timing
import geofeat.descriptors.describer
import geofeat.gpu
import geofeat.matching
from geofeat.bench.runner import BenchConfig
from geofeat.cli import main
from geofeat.sim import simulate_sequence

SMALL = dict(width=320, height=240, progress=False)


@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    """Two small simulated sequences of three frames (two objects, for retrieval)."""
    root = tmp_path_factory.mktemp("devices")
    simulate_sequence(root / "a-deform", scenario="deform", n_frames=3, seed=11, **SMALL)
    simulate_sequence(root / "b-deform", scenario="deform", n_frames=3, seed=12, **SMALL)
    return root


@pytest.fixture
def fake_gpu(monkeypatch):
    """A usable GPU, as far as geofeat asks (`require_cuda` passes); descriptors made for it
    (device=, backend=) are made on the CPU, their `compute_cuda` standing in as `compute`, and
    `build_mesh_cuda` gives nothing. Records what was made (name, {device, backend}), what was
    described on the "GPU" and the device of every `geofeat.match`."""
    seen = SimpleNamespace(made=[], described=[], matched=[])
    make, match = geofeat.descriptors.describer.make_descriptor, geofeat.matching.match

    def recording_make(name, **kwargs):
        seen.made.append((name, {k: kwargs.pop(k) for k in ("device", "backend") if k in kwargs}))
        descriptor = make(name, **kwargs)

        def compute_cuda(frame, kps, mesh=None):
            seen.described.append(name)
            return SimpleNamespace(to_host=lambda: descriptor.compute(frame, kps))

        descriptor.compute_cuda = compute_cuda
        return descriptor

    def recording_match(f0, f1, *args, device=None, **kwargs):
        seen.matched.append(device)
        return match(f0, f1, *args, **kwargs)

    monkeypatch.setattr(geofeat.gpu, "require_cuda", lambda device="cuda": None)
    monkeypatch.setattr(geofeat.gpu, "build_mesh_cuda", lambda frame, config, device=None: None)
    for module in (geofeat.descriptors.describer, geofeat.bench.timing):
        monkeypatch.setattr(module, "make_descriptor", recording_make)
    for module in (geofeat.matching, geofeat.bench.runner, geofeat.bench.timing):
        monkeypatch.setattr(module, "match", recording_match)
    return seen


def read_rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_bench_device_describes_and_matches_geopatch_on_the_gpu_and_records_it(sequences, tmp_path, fake_gpu,
                                                                              capsys):
    """`bench --device cuda:0`: GeoPatch made with the torch backend on that device, described with
    `compute_cuda` and matched there, GeoBit on the CPU; results.csv gives each row its device,
    config.json the run's, table.md names both; a rerun into OUT on the CPU is refused (its timings
    would be mixed with the GPU's). Without --device nothing goes to the GPU and every row says cpu."""
    args = ["bench", str(sequences / "a-deform"), "--descriptors", "geopatch,geobit", "--keypoints", "100"]
    assert main([*args, "--out", str(tmp_path / "gpu"), "--device", "cuda:0"]) == 0
    assert fake_gpu.made == [("geopatch", {"device": "cuda:0", "backend": "torch"}), ("geobit", {})]
    assert set(fake_gpu.described) == {"geopatch"} and len(fake_gpu.described) == 4  # warm-up, reference, 2 targets
    assert fake_gpu.matched == ["cuda:0", None] * 2  # 2 pairs, geopatch's on the GPU
    rows = read_rows(tmp_path / "gpu" / "results.csv")
    assert {(r["descriptor"], r["device"]) for r in rows} == {("geopatch", "cuda:0"), ("geobit", "cpu")}
    assert json.loads((tmp_path / "gpu" / "config.json").read_text())["device"] == "cuda:0"
    assert "Device: cpu (geobit); cuda:0 (geopatch)." in (tmp_path / "gpu" / "table.md").read_text()
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "gpu")]) == 2
    assert "device cuda:0 there, the CPU now" in capsys.readouterr().err

    fake_gpu.made.clear(), fake_gpu.described.clear(), fake_gpu.matched.clear()
    assert main([*args, "--out", str(tmp_path / "cpu")]) == 0
    assert fake_gpu.made == [("geopatch", {}), ("geobit", {})] and not fake_gpu.described
    assert fake_gpu.matched == [None] * 4
    cpu = read_rows(tmp_path / "cpu" / "results.csv")
    assert {r["device"] for r in cpu} == {"cpu"} and "Device:" not in (tmp_path / "cpu" / "table.md").read_text()
    assert json.loads((tmp_path / "cpu" / "config.json").read_text())["device"] is None
    # the stand-in computes what the CPU computes: the same scores, whatever the device
    assert [(r["descriptor"], r["ms"]) for r in cpu] == [(r["descriptor"], r["ms"]) for r in rows]


def test_bench_config_takes_cpu_as_the_default_run_and_refuses_a_device_nothing_uses():
    """`BenchConfig(device=...)`: "cpu" is the default run (config.json: null, so that it resumes a
    run without a device); another value, or CUDA for descriptors that do not run there, is a
    ValueError naming `device`."""
    assert BenchConfig(descriptors=("geobit",), device="cpu").device is None
    assert BenchConfig(descriptors=("geopatch", "sift"), device="cuda:1").device == "cuda:1"
    for descriptors, device, message in [(("geobit",), "tpu", "expected None, 'cpu' or 'cuda"),
                                         (("geobit", "sift"), "cuda", "none of geobit, sift is GeoPatch")]:
        with pytest.raises(ValueError, match=message):
            BenchConfig(descriptors=descriptors, device=device)


def test_timing_table_times_geopatch_on_the_device(sequences, fake_gpu):
    """`bench --timing` with a device: GeoPatch's extraction (`compute_cuda`) and matching timed on
    it, the rows saying so; the other descriptors as on the CPU."""
    from geofeat.bench.timing import timing_table
    from geofeat.io import read_sequence

    seq = read_sequence(sequences / "a-deform")
    table = timing_table(seq.frame(seq.reference), ("geopatch", "orb"), 0.075, counts=(30,), repeat=1,
                         depth_profile="clean", device="cuda")
    assert "| geopatch extraction on cuda (its mesh, f(.) and CNN there) |" in table
    assert "| geopatch matching (N x N) on cuda |" in table and "| orb matching (N x N) |" in table
    assert fake_gpu.described == ["geopatch"] and fake_gpu.matched == ["cuda", None]


def test_track_device_describes_and_matches_geopatch_on_the_gpu(sequences, tmp_path, fake_gpu):
    """`track --device cuda`: GeoPatch described on the GPU path and its mutual matches searched there
    (`geofeat.match(..., device=)`), SIFT on the CPU; tracking.md says which ran where. Without it,
    nothing goes to the GPU."""
    args = ["track", str(sequences / "a-deform"), "--descriptors", "geopatch,sift", "--keypoints", "300",
            "--refine", "none"]
    assert main([*args, "--out", str(tmp_path / "gpu"), "--device", "cuda"]) == 0
    made = dict(fake_gpu.made)
    assert made == {"geopatch": {"device": "cuda", "backend": "torch"}, "sift": {}}
    assert fake_gpu.described == ["geopatch"] * 3  # the template and the two target frames
    assert sorted(map(str, fake_gpu.matched)) == ["None", "None", "cuda", "cuda"]  # the two target frames
    assert "geopatch described and matched on cuda" in (tmp_path / "gpu" / "tracking.md").read_text()
    fake_gpu.made.clear(), fake_gpu.matched.clear()
    assert main([*args, "--out", str(tmp_path / "cpu")]) == 0
    assert dict(fake_gpu.made) == {"geopatch": {}, "sift": {}} and fake_gpu.matched == [None] * 4
    assert "matched on" not in (tmp_path / "cpu" / "tracking.md").read_text()


def test_retrieval_device_describes_geopatch_and_reranks_its_matches_on_the_gpu(sequences, tmp_path, fake_gpu):
    """`retrieval --device cuda`: GeoPatch described on the GPU path and the matches of its re-ranking
    searched there, ORB on the CPU (the words' matching too); the same results as the CPU run."""
    args = ["retrieval", str(sequences), "--descriptors", "geopatch,orb", "--keypoints", "100", "--samples", "300",
            "--words", "20", "--rerank", "3", "--include-own-sequence"]
    assert main([*args, "--out", str(tmp_path / "gpu"), "--device", "cuda"]) == 0
    assert dict(fake_gpu.made) == {"geopatch": {"device": "cuda", "backend": "torch"}, "orb": {}}
    assert fake_gpu.described == ["geopatch"] * 6
    # per descriptor: the words of 6 frames, then 2 queries x 3 results re-ranked; only geopatch's re-ranking on the GPU
    assert fake_gpu.matched.count("cuda") == 6 and fake_gpu.matched.count(None) == 6 + 6 + 6
    fake_gpu.made.clear(), fake_gpu.matched.clear()
    assert main([*args, "--out", str(tmp_path / "cpu")]) == 0
    assert dict(fake_gpu.made) == {"geopatch": {}, "orb": {}} and set(fake_gpu.matched) == {None}
    assert read_rows(tmp_path / "gpu" / "retrieval.csv") == read_rows(tmp_path / "cpu" / "retrieval.csv")


@pytest.mark.parametrize("command", ["bench", "track", "retrieval"])
def test_device_of_several_descriptors_is_refused_clearly_where_it_cannot_run(sequences, tmp_path, capsys, command):
    """`--device` of the commands that run several descriptors: extract's checks, one-line usage errors
    naming the flag before any frame is read, for a device that is neither the CPU nor CUDA, for
    descriptors none of which the GPU path computes, for GeoPatch from an .onnx file and, on a machine
    without a CUDA GPU, for CUDA itself."""
    onnx = tmp_path / "x.onnx"
    onnx.write_bytes(b"")  # the name's own check wants the file to exist
    cases = [(["--device", "tpu"], "--device: expected cpu, cuda or cuda:N, got 'tpu'"),
             (["--device", "cuda", "--descriptors", "geobit,sift"], "--device cuda: the GPU path computes GeoPatch "
                                                                    "only, and --descriptors geobit,sift names none"),
             (["--device", "cuda", "--descriptors", f"sift,geopatch={onnx}"], f"not geopatch={onnx}")]
    if not torch.cuda.is_available():
        cases.append((["--device", "cuda:0", "--descriptors", "GeoPatch,sift"], "--device cuda:0: "))
    out = tmp_path / "out"
    for extra, message in cases:
        assert main([command, str(sequences), "--out", str(out), "--keypoints", "50", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith(f"geofeat {command}: error: ") and message in err, (extra, err)
    assert not out.exists()


def test_app_functions_refuse_a_device_no_descriptor_uses(sequences, tmp_path):
    """`write_tracking`, `track_sequence` and `run_retrieval` take `device` as the bench does: CUDA
    for descriptors none of which runs there, or a device that is not one, is a ValueError naming
    `device` before any work."""
    from geofeat.apps.retrieval import run_retrieval
    from geofeat.apps.tracking import track_sequence, write_tracking

    seq = sequences / "a-deform"
    calls = [lambda device: write_tracking([seq], tmp_path / "t", ("sift",), device=device, progress=False),
             lambda device: track_sequence(seq, ("sift", "orb"), device=device, progress=False),
             lambda device: run_retrieval([sequences], tmp_path / "r", ("sift",), include_own_sequence=True,
                                          device=device, progress=False)]
    for call in calls:
        with pytest.raises(ValueError, match="device: 'cuda' .* none of sift.* is GeoPatch"):
            call("cuda")
        with pytest.raises(ValueError, match="device: expected None, 'cpu' or 'cuda"):
            call("gpu")
    assert not (tmp_path / "t").exists() and not (tmp_path / "r").exists()


SIMULATED_DESCRIBER = SMALL_FRAME + r'''
import geofeat.descriptors.describer as describer
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.gpu import simulated
from geofeat.keypoints import Keypoints
assert simulated()
kps = Keypoints(np.array([[24.2, 20.3], [20.7, 17.1], [27.4, 22.6], [2.5, 3.5]]), np.full(4, 30.0), np.full(4, 8.0),
                np.zeros(4))
make, made = describer.make_descriptor, []

def on_the_simulated_gpu(name, **kwargs):  # torch sees no CUDA GPU here: the simulator's "GPU" is the CPU
    made.append((name, kwargs.get("device"), kwargs.get("backend")))
    return make(name, **dict(kwargs, device="cpu") if "device" in kwargs else kwargs)

describer.make_descriptor = on_the_simulated_gpu
gpu = describer.Describer(("geopatch", "sift"), 0.075, "clean", device="cuda")
cpu = describer.Describer(("sift",), 0.075, "clean")
assert made == [("geopatch", "cuda", "torch"), ("sift", None, None), ("sift", None, None)], made
got = gpu(frame, kps)
ref = GeoPatch(device="cpu", backend="torch", depth_config="clean").compute(frame, kps)
assert isinstance(got["geopatch"][0].descriptors, np.ndarray) and got["geopatch"][1] > 0
np.testing.assert_array_equal(got["geopatch"][0].valid, ref.valid)
np.testing.assert_allclose(got["geopatch"][0].descriptors, ref.descriptors, rtol=0, atol=1e-4)
np.testing.assert_array_equal(got["sift"][0].descriptors, cpu(frame, kps)["sift"][0].descriptors)
assert gpu.match_device("geopatch") == "cuda" and gpu.match_device("sift") is None
print("ok")
'''


def test_describer_on_the_gpu_path_in_cuda_simulator():
    """`Describer(..., device="cuda")` on the GPU path itself (its mesh built there, walk kernel
    simulated, torch on CPU tensors): GeoPatch's host features equal the CPU torch backend's within
    1e-4, SIFT's are the CPU's, and GeoPatch's features are to be matched on the device."""
    run_simulated(SIMULATED_DESCRIBER)
