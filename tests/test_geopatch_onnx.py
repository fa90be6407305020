"""GeoPatch through ONNX Runtime: fp32 equals torch, int8 is close and matches alike, backends are
chosen and named clearly, and the ONNX path does not import torch. No timings (see
benchmarks/bench_pipeline.py)."""

import importlib.util
import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

import geofeat  # noqa: E402
from geofeat.descriptors.geopatch import GeoPatch, default_weights_path  # noqa: E402
from geofeat.descriptors.geopatch_onnx import (BACKEND_ENV, ONNX_INT8_NAME, ONNX_NAME, data_path,  # noqa: E402
                                               file_sha256)
from geofeat.frame import rotate_points90  # noqa: E402
from geofeat.keypoints import detect  # noqa: E402


@pytest.fixture(scope="module")
def kinect_pair():
    """Polar patches of the Kinect frame's keypoints and of the same points in its 90-degree roll."""
    frame = geofeat.read_demo_frame()
    rolled = frame.rotated90(1)
    xy = detect(frame, 2048, detector="sift").xy
    a = geofeat.polar_patches(frame, xy)
    b = geofeat.polar_patches(rolled, rotate_points90(xy, frame.shape, 1))
    ok = a.valid & b.valid
    return a.values[ok], b.values[ok]


@pytest.fixture(scope="module")
def torch_net():
    return GeoPatch(device="cpu", backend="torch")


def test_shipped_models_exist_and_come_from_the_shipped_weights():
    sha = file_sha256(default_weights_path())
    import onnxruntime as ort

    for name in (ONNX_NAME, ONNX_INT8_NAME):
        path = data_path(name)
        assert path.is_file(), f"{path} missing: rebuild with benchmarks/make_geopatch_onnx.py"
        meta = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta()
        assert meta.custom_metadata_map["source_sha256"] == sha, f"{name} is stale: rerun make_geopatch_onnx.py"
        assert json.loads(meta.custom_metadata_map["config"])["dim"] == 128


def test_fp32_equals_torch(kinect_pair, torch_net):
    values, _ = kinect_pair
    rng = np.random.default_rng(0)
    extra = np.concatenate([rng.random((40, 32, 32)), np.full((1, 32, 32), 0.5)]).astype(np.float32)  # + a flat patch
    x = np.concatenate([values, extra])
    valid = np.ones(len(x), bool)
    valid[::7] = False
    ref = torch_net.describe(x, valid)
    for batch in (1000, 64):
        got = GeoPatch(backend="onnx", batch_size=batch, threads=1).describe(x, valid)
        np.testing.assert_allclose(got, ref, atol=1e-4, rtol=0)
        assert (got[~valid] == 0).all()


def _needs(backend: str) -> None:
    if backend.startswith("openvino"):
        pytest.importorskip("openvino")


@pytest.mark.parametrize("backend", ["onnx-int8", "openvino-int8"])
def test_int8_is_close_and_matches_like_torch(kinect_pair, torch_net, backend):
    _needs(backend)
    a, b = kinect_pair
    assert len(a) >= 1500
    int8 = GeoPatch(backend=backend)
    ref_a, ref_b = torch_net.describe(a), torch_net.describe(b)
    got_a, got_b = int8.describe(a), int8.describe(b)
    cosine = np.concatenate([(got_a * ref_a).sum(1), (got_b * ref_b).sum(1)])
    assert cosine.mean() > 0.98 and cosine.min() > 0.9, (cosine.mean(), cosine.min())

    def nearest(d0, d1):
        return np.argmin(((d0[:, None] - d1[None]) ** 2).sum(-1), axis=1)

    agree = (nearest(got_a, got_b) == nearest(ref_a, ref_b)).mean()
    assert agree >= 0.95, agree


@pytest.mark.parametrize("backend", ["onnx", "onnx-int8", "openvino-int8", "openvino-bf16"])
def test_rotated_frame_gives_the_same_descriptors(kinect_pair, backend):
    """The same points seen in the frame and in its 90-degree roll get descriptors nearer to each
    other than to other points' (as with torch), and column shifts by multiples of 4 (the two
    pooling strides) leave the fp32 descriptors unchanged."""
    _needs(backend)
    a, b = kinect_pair
    g = GeoPatch(backend=backend)
    da, db = g.describe(a), g.describe(b)
    same = np.linalg.norm(da - db, axis=1)
    between = np.linalg.norm(da[:200, None] - da[None, :200], axis=-1)[~np.eye(200, dtype=bool)].mean()
    assert np.median(same) < 0.25 * between, (np.median(same), between)
    shifted = g.describe(np.roll(a[:100], 8, axis=2))
    tol = 1e-5 if backend == "onnx" else 0.1
    assert np.abs(shifted - da[:100]).max() < tol


def test_backend_names_and_the_environment_variable(monkeypatch, tmp_path):
    with pytest.raises(ValueError, match="backend.*onnx-int8"):
        GeoPatch(backend="tensorrt")
    monkeypatch.setenv(BACKEND_ENV, "onnx")
    assert GeoPatch().backend == "onnx"
    assert GeoPatch(backend="torch").backend == "torch"  # the argument wins over the variable
    monkeypatch.setenv(BACKEND_ENV, "fast")
    with pytest.raises(ValueError, match=BACKEND_ENV):
        GeoPatch()
    monkeypatch.delenv(BACKEND_ENV)
    if importlib.util.find_spec("openvino"):
        from geofeat.descriptors.geopatch_openvino import cpu_has_bf16

        expected = "openvino-bf16" if cpu_has_bf16() else "openvino-int8"
    else:
        expected = "onnx-int8"
    assert GeoPatch(device="cpu").backend == expected
    with pytest.raises(ValueError, match="CPU"):
        GeoPatch(backend="onnx", device="cuda")


def test_openvino_runs_the_int8_model_like_onnxruntime(kinect_pair):
    """OpenVINO and ONNX Runtime run the same int8 model: descriptors within 0.03, cosine > 0.99, and
    the same nearest neighbour (frame -> roll) for nearly every point."""
    pytest.importorskip("openvino")
    a, b = kinect_pair
    ort, ov = GeoPatch(backend="onnx-int8"), GeoPatch(backend="openvino-int8", batch_size=100)
    assert ov.config == ort.config
    da_ort, db_ort = ort.describe(a), ort.describe(b)
    da_ov, db_ov = ov.describe(a), ov.describe(b)
    assert np.abs(da_ov - da_ort).max() < 0.03
    assert (da_ov * da_ort).sum(1).min() > 0.99

    def nearest(d0, d1):
        return np.argmin(((d0[:, None] - d1[None]) ** 2).sum(-1), axis=1)

    assert (nearest(da_ov, db_ov) == nearest(da_ort, db_ort)).mean() >= 0.99


def test_bf16_is_within_cosine_0999_of_torch_and_matches_alike(kinect_pair, torch_net):
    """bfloat16 on float32-z-scored patches stays close to torch's float32 descriptors (where the CPU
    has no bfloat16, OpenVINO runs float32 and this holds a fortiori); a flat patch stays finite."""
    pytest.importorskip("openvino")
    a, b = kinect_pair
    g = GeoPatch(backend="openvino-bf16", batch_size=100)
    flat = np.full((1, 32, 32), 0.5, np.float32)
    got_a, got_b = g.describe(np.concatenate([a, flat])), g.describe(b)
    assert np.isfinite(got_a).all()
    got_a = got_a[:-1]
    ref_a, ref_b = torch_net.describe(a), torch_net.describe(b)
    cosine = np.concatenate([(got_a * ref_a).sum(1), (got_b * ref_b).sum(1)])
    assert cosine.min() > 0.999, cosine.min()

    def nearest(d0, d1):
        return np.argmin(((d0[:, None] - d1[None]) ** 2).sum(-1), axis=1)

    assert (nearest(got_a, got_b) == nearest(ref_a, ref_b)).mean() >= 0.99
    with pytest.raises(ValueError, match="onnx"):
        GeoPatch(weights=str(default_weights_path()), backend="openvino-bf16")


def test_zscore_matches_the_networks_normalisation():
    pytest.importorskip("openvino")
    import torch

    from geofeat.descriptors.geopatch_net import GeoPatchNet
    from geofeat.descriptors.geopatch_openvino import zscore_patches

    x = (np.random.default_rng(2).random((7, 32, 32)) * 255).astype(np.float32)
    x[3] = 17.0  # flat: 0, not NaN
    expected = GeoPatchNet.normalise(torch.from_numpy(x)[:, None])[:, 0].numpy()
    got = zscore_patches(x)
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0)
    assert (got[3] == 0).all()
    assert zscore_patches(np.zeros((0, 32, 32), np.float32)).shape == (0, 32, 32)


def test_user_weights_use_torch_or_are_exported_on_the_fly(tmp_path):
    pytest.importorskip("onnx")
    import torch

    from geofeat.descriptors.geopatch_net import GeoPatchConfig, GeoPatchNet, save_checkpoint

    torch.manual_seed(0)
    net = GeoPatchNet(GeoPatchConfig(channels=(4, 8, 8), dim=16)).eval()
    for bn in (net.features[1], net.features[5], net.features[9]):  # non-trivial batch norm to fold
        bn.running_mean.uniform_(-0.5, 0.5)
        bn.running_var.uniform_(0.5, 2)
    path = tmp_path / "w.pt"
    save_checkpoint(path, net)
    torch_g = GeoPatch(weights=str(path), device="cpu")
    assert torch_g.backend == "torch"
    onnx_g = GeoPatch(weights=str(path), backend="onnx")
    x = np.random.default_rng(1).random((50, 32, 32)).astype(np.float32)
    np.testing.assert_allclose(onnx_g.describe(x), torch_g.describe(x), atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="int8"):
        GeoPatch(weights=str(path), backend="onnx-int8")


def test_onnx_backend_does_not_import_torch():
    code = ("import sys, numpy as np, geofeat\n"
            "g = geofeat.make_descriptor('geopatch')\n"
            "f = g.compute(geofeat.read_demo_frame(), np.array([[320.0, 240.0], [300.0, 200.0]]))\n"
            "assert g.backend in ('onnx-int8', 'openvino-int8', 'openvino-bf16') and f.descriptors.shape == (2, 128)\n"
            "assert 'torch' not in sys.modules, 'torch was imported'\n")
    env = {k: v for k, v in os.environ.items() if k != BACKEND_ENV}
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_openvino_compiles_each_model_once_per_process():
    """GeoPatch objects made one after another (as `geofeat.extract` does per frame) share the
    compiled model and keep their own inference request."""
    pytest.importorskip("openvino")
    for backend in ("openvino-int8", "openvino-bf16"):
        a, b = GeoPatch(backend=backend), GeoPatch(backend=backend)
        assert a.session.compiled is b.session.compiled
        assert a.session.request is not b.session.request
    assert GeoPatch(backend="openvino-int8").session.compiled is not GeoPatch(backend="openvino-bf16").session.compiled


@pytest.mark.parametrize("backend", ["openvino-int8", "openvino-bf16"])
def test_openvino_streams_give_the_one_thread_descriptors(kinect_pair, backend):
    """With 2 threads the batches run on two streams (one thread each) and come back in order: the
    same descriptors as one thread, for a count that is not a multiple of the batch, and for one
    batch."""
    pytest.importorskip("openvino")
    a, _ = kinect_pair
    x = a[:1000]
    one, two = GeoPatch(backend=backend, threads=1), GeoPatch(backend=backend, threads=2, batch_size=96)
    assert two.session.queue is not None and one.session.queue is None
    ref = one.describe(x)
    np.testing.assert_allclose(two.describe(x), ref, atol=1e-6, rtol=0)
    np.testing.assert_allclose(two.describe(x[:50]), ref[:50], atol=1e-6, rtol=0)


@pytest.mark.parametrize("backend", ["torch", "onnx", "onnx-int8", "openvino-int8", "openvino-bf16"])
def test_every_backend_refuses_nan_in_a_valid_patch(backend):
    """A NaN or inf value in a patch marked valid made a NaN descriptor in torch and fp32 ONNX, and an
    ordinary-looking finite one in the int8 and OpenVINO backends (their quantisation swallowed it):
    one ValueError naming the patches instead; NaN in an invalid patch is fine (its row is 0)."""
    if backend.startswith("openvino"):
        pytest.importorskip("openvino")
    g = GeoPatch(backend=backend, device="cpu")
    x = np.random.default_rng(0).random((3, 32, 32)).astype(np.float32)
    for bad in (np.nan, np.inf):
        x[1, 4, 5] = bad
        with pytest.raises(ValueError, match="patch_values: .*valid patches \\[1\\]"):
            g.describe(x)
    out = g.describe(x, np.array([True, False, True]))
    assert (out[1] == 0).all() and np.isfinite(out).all()


def test_openvino_refuses_a_file_that_is_not_a_model_like_onnxruntime(tmp_path):
    """A corrupt .onnx file was OpenVINO's "Exception from src/inference/src/cpp/core.cpp ..."
    RuntimeError; ONNX Runtime's is already a ValueError naming the weights."""
    pytest.importorskip("openvino")
    path = tmp_path / "broken.onnx"
    path.write_text("not a model")
    for backend in ("onnx", "openvino-int8", "openvino-bf16"):
        with pytest.raises(ValueError, match="weights: .*broken.onnx is not a GeoPatch ONNX model"):
            GeoPatch(weights=str(path), backend=backend)


def test_a_backend_from_the_environment_variable_that_cannot_run_says_so(monkeypatch, tmp_path):
    """With GEOFEAT_GEOPATCH_BACKEND=onnx-int8 set (as BENCHMARKS.md runs `bench`), `geopatch=mine.pt`
    said 'backend: onnx-int8 needs a calibrated int8 model ... or use backend='onnx' or 'torch'', and
    GeoPatch(device='cuda') 'the onnx-int8 backend runs on CPU only': a backend nobody had passed, with
    advice for an argument a command line user cannot give."""
    from geofeat import make_descriptor
    from geofeat.descriptors.geopatch import GeoPatchConfig, GeoPatchNet, save_checkpoint

    save_checkpoint(tmp_path / "mine.pt", GeoPatchNet(GeoPatchConfig(channels=(4, 4, 4))))
    monkeypatch.setenv(BACKEND_ENV, "onnx-int8")
    env = rf"chosen by the environment variable {BACKEND_ENV}=onnx-int8: set it to a backend that runs"
    with pytest.raises(ValueError, match=r"backend: onnx-int8 needs a calibrated int8 model.*" + env):
        make_descriptor(f"geopatch={tmp_path / 'mine.pt'}")
    with pytest.raises(ValueError, match=r"runs on CPU only.*" + env):
        GeoPatch(device="cuda")
    with pytest.raises(ValueError) as caught:  # an argument names its own backend: no word of the variable
        GeoPatch(weights=tmp_path / "mine.pt", backend="onnx-int8")
    assert BACKEND_ENV not in str(caught.value)
    with pytest.raises(ValueError) as caught:  # not the backend's fault
        GeoPatch(weights=tmp_path / "missing.onnx")
    assert "no GeoPatch ONNX model" in str(caught.value) and BACKEND_ENV not in str(caught.value)
