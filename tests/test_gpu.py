"""The GPU path (`geofeat.gpu`, `extract(..., device="cuda")`, `match(..., device=...)`) against the
CPU path.

Without a GPU: the torch parts of the path (blur, patch sampling, CNN on tensors, L2 / Hamming
matching as matrix products) run on CPU tensors and are compared with the CPU path's functions; the
walk kernel is compared in numba's CUDA simulator (tests/test_walk_cuda.py); asking for CUDA raises
a clear error. With a GPU, the whole path runs on the shipped Kinect frame and its 90-degree roll.

Tolerances (stated in `geofeat.gpu`): blur and patch values 1e-6 (float32 summation order),
descriptors 1e-4, matches identical.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
import torch

import geofeat
from geofeat.descriptors.geobit import GeoBit
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.geodesic.polar import sample_bilinear, sampling_image
from geofeat.gpu import gaussian_blur_torch, match_cuda, sample_bilinear_torch
from geofeat.keypoints import detect
from geofeat.matching import match

CUDA = torch.cuda.is_available()


@pytest.fixture(scope="module")
def pair():
    f0 = geofeat.read_demo_frame()
    f1 = f0.rotated90(1)
    return [(f, detect(f, 512, detector="sift")) for f in (f0, f1)]


def test_blur_and_sampling_equal_opencv(pair):
    frame = pair[0][0]
    img = sampling_image(frame, 1.0)
    blurred = gaussian_blur_torch(torch.from_numpy(frame.image), 1.0).numpy()
    np.testing.assert_allclose(blurred, img, rtol=0, atol=1e-6)
    rng = np.random.default_rng(0)
    H, W = img.shape
    # inside, on and off the border (replicated), and the walk's own coordinates
    coords = np.concatenate([rng.uniform([-5, -5], [W + 5, H + 5], (20000, 2)),
                             np.array([[0, 0], [W - 1, H - 1], [W - 1.5, 3.25], [-0.5, H - 0.5]])]).astype(np.float32)
    p = geofeat.polar_patches(frame, pair[0][1][:64])
    coords = np.concatenate([coords, p.coords[p.valid].reshape(-1, 2)])
    got = sample_bilinear_torch(torch.from_numpy(img), torch.from_numpy(coords)).numpy()
    np.testing.assert_allclose(got, sample_bilinear(img, coords), rtol=0, atol=1e-6)
    nan = sample_bilinear_torch(torch.from_numpy(img), torch.full((3, 2), float("nan")))
    assert (nan == 0).all()


def test_blur_of_a_frame_smaller_than_the_kernel_equals_opencv():
    """The GPU's sampling blur on a frame narrower than the Gaussian's radius (a blur_px of 20, which
    `check_blur_px` accepts, has a radius of 80 px; 1 px, the default, of 4): OpenCV reflects the
    border again and again, the CPU path worked; torch's reflection padding refused such a pad
    ("Padding size should be less than the corresponding input dimension")."""
    import cv2

    rng = np.random.default_rng(2)
    for shape in ((48, 64), (3, 40), (6, 5), (1, 7), (7, 1)):
        img = rng.random(shape).astype(np.float32)
        for sigma in (1.0, 5.0, 20.0):
            got = gaussian_blur_torch(torch.from_numpy(img), sigma).numpy()
            np.testing.assert_allclose(got, cv2.GaussianBlur(img, (0, 0), sigma), rtol=0, atol=1e-6)


def test_sampling_in_opencv_4s_subpixel_steps(pair):
    """OpenCV 4's cv2.remap (pyproject allows >= 4.8) rounds float coordinates to 1/32 pixel before
    interpolating; OpenCV 5's does not. The GPU sampler follows the installed OpenCV
    (`remap_subpixel_steps`): under OpenCV 4.10 the test above failed by 4.6e-3 on this frame, the
    CPU's values quantised and the GPU's not. Here the 1/32 form, whatever OpenCV is installed,
    against a float64 reference of OpenCV 4's rule (round half to even, products of the fractions
    as weights, border replicated), within 1e-6."""
    from geofeat.gpu import remap_subpixel_steps

    assert remap_subpixel_steps() in (None, 32)
    img = sampling_image(pair[0][0], 1.0)
    H, W = img.shape
    rng = np.random.default_rng(1)
    coords = np.concatenate([rng.uniform([-3, -3], [W + 3, H + 3], (20000, 2)),
                             (rng.integers(-64, 32 * W + 64, (2000, 2)) + 0.5) / 32,  # halfway: ties to even
                             [[W - 1 + 31.5 / 32, H - 1], [-0.5 / 32, 0.0]]]).astype(np.float32)
    got = sample_bilinear_torch(torch.from_numpy(img), torch.from_numpy(coords), steps=32).numpy()
    q = np.rint(coords.astype(np.float64) * 32).astype(np.int64)
    x0, y0 = q[:, 0] // 32, q[:, 1] // 32
    fx, fy = (q[:, 0] % 32) / 32, (q[:, 1] % 32) / 32
    xa, xb, ya, yb = np.clip(x0, 0, W - 1), np.clip(x0 + 1, 0, W - 1), np.clip(y0, 0, H - 1), np.clip(y0 + 1, 0, H - 1)
    ref = ((1 - fy) * ((1 - fx) * img[ya, xa] + fx * img[ya, xb]) + fy * ((1 - fx) * img[yb, xa] + fx * img[yb, xb]))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)
    exact = sample_bilinear_torch(torch.from_numpy(img), torch.from_numpy(coords), steps=None).numpy()
    assert np.abs(exact - got).max() > 1e-3  # the rounding matters on this image


def test_depth_smoothing_on_tensors_equals_opencv(pair):
    """The GPU path's depth preprocessing (`smooth_depth_torch`, `backproject_torch`) on CPU tensors
    against `depth.smooth` / `depth.backproject`, on the real Kinect frame (holes filled first, as
    both paths do) for both profiles: the same missing pixels, depths within two float32 ulp."""
    from geofeat.depth import PROFILES, backproject, fill_holes, smooth
    from geofeat.gpu import backproject_torch, smooth_depth_torch

    frame = pair[0][0]
    depth = fill_holes(frame.depth)
    for cfg in PROFILES.values():
        ref = smooth(depth, cfg.smooth_levels, cfg.mesh_scale)
        got = smooth_depth_torch(torch.from_numpy(depth), cfg.smooth_levels, cfg.mesh_scale).numpy()
        assert got.shape == ref.shape and got.dtype == np.float32
        np.testing.assert_array_equal(got > 0, ref > 0)
        assert (ref == 0).any() and (ref > 0).mean() > 0.5
        np.testing.assert_allclose(got, ref, rtol=0, atol=2 * np.spacing(np.float32(ref.max())))
        np.testing.assert_array_equal(backproject_torch(torch.from_numpy(ref), frame.K).numpy(),
                                      backproject(ref, frame.K))


def test_gpu_pyramid_reads_the_cpu_pyramids_rules(pair, monkeypatch):
    """The pyramid's rules are constants of `geofeat.depth` (HALVE_MIN_VALID, RESIZE_MIN_WEIGHT) that
    the GPU pyramid reads rather than repeats (they were literals in both files): changed on the
    CPU side, the GPU follows, the same missing pixels on the Kinect frame (both resize branches:
    640 x 480, covered by the pyramid, and a 637 x 478 crop, which is not)."""
    from geofeat import depth as host
    from geofeat.depth import fill_holes, smooth
    from geofeat.gpu import smooth_depth_torch

    depth = fill_holes(pair[0][0].depth)
    monkeypatch.setattr(host, "HALVE_MIN_VALID", 4)
    monkeypatch.setattr(host, "RESIZE_MIN_WEIGHT", 0.9)
    for d in (depth, np.ascontiguousarray(depth[:478, :637])):
        ref = smooth(d, 2, 0.5)
        got = smooth_depth_torch(torch.from_numpy(d), 2, 0.5).numpy()
        np.testing.assert_array_equal(got > 0, ref > 0)
        np.testing.assert_allclose(got, ref, rtol=0, atol=2 * np.spacing(np.float32(ref.max())))
    monkeypatch.undo()
    assert (ref > 0).sum() < (smooth(np.ascontiguousarray(depth[:478, :637]), 2, 0.5) > 0).sum()  # they mattered


def test_a_frame_the_pyramid_does_not_cover_copies_its_resampling_once(pair, monkeypatch):
    """`smooth_depth_torch` copied the resampling matrices of a frame the pyramid does not cover (sides
    not multiples of 4) from the host on every call: inside `FrameGraph`'s CUDA graph capture, which
    refuses host-to-device copies, such a frame could not be captured. They are made once per size."""
    from geofeat.depth import fill_holes
    from geofeat.gpu import smooth_depth_torch

    d = np.ascontiguousarray(fill_holes(pair[0][0].depth)[:478, :637])
    first = smooth_depth_torch(torch.from_numpy(d), 2, 0.5)

    def no_copy(*args, **kwargs):
        raise AssertionError("a copy from the host on a later frame")

    monkeypatch.setattr(torch, "as_tensor", no_copy)
    np.testing.assert_array_equal(smooth_depth_torch(torch.from_numpy(d), 2, 0.5).numpy(), first.numpy())


def test_describe_tensor_equals_describe(pair):
    frame, kps = pair[0]
    p = geofeat.polar_patches(frame, kps)
    net = GeoPatch(device="cpu", backend="torch")
    ref = net.describe(p.values, p.valid)
    got = net.describe_tensor(torch.from_numpy(p.values), torch.from_numpy(p.valid)).numpy()
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-4)
    assert (got[~p.valid] == 0).all()


@pytest.mark.parametrize("mutual,ratio", [(False, None), (True, None), (False, 0.9), (True, 0.8)])
def test_l2_matching_as_matrix_product_equals_cpu(pair, mutual, ratio):
    net = GeoPatch(device="cpu", backend="torch")
    f0, f1 = (net.compute(f, k) for f, k in pair)
    ref = match(f0, f1, mutual=mutual, ratio=ratio)
    got = match(f0, f1, mutual=mutual, ratio=ratio, device="cpu")
    np.testing.assert_array_equal(got.matches0, ref.matches0)
    np.testing.assert_allclose(got.distances0, ref.distances0, rtol=0, atol=1e-5)
    assert (ref.matches0 >= 0).sum() > 50


def test_hamming_on_tensors_equals_cpu(pair):
    gb = GeoBit()
    f0, f1 = (gb.compute(f, k) for f, k in pair)
    ref = match(f0, f1, mutual=True)
    from geofeat.matching import _finish_matches, _hamming_search_torch

    t = [torch.from_numpy(x) for x in (f0.descriptors, f1.descriptors, f0.valid, f1.valid)]
    got = _finish_matches(*_hamming_search_torch(*t, True, "cpu"), ratio=None, mutual=True)
    np.testing.assert_array_equal(got.matches0, ref.matches0)
    np.testing.assert_array_equal(got.distances0, ref.distances0)


@pytest.mark.parametrize("n_bytes,rotations", [(256, 1), (256, 4), (512, 1), (512, 4)])
def test_hamming_in_the_cuda_dtype_equals_cpu(n_bytes, rotations):
    """The GPU's Hamming search multiplies {0, 1} bit matrices in the dtype `_hamming_dot_dtype` picks
    for CUDA, run here on CPU tensors: the same matches and distances as the CPU's numba search, for
    descriptors of 256 bytes (2048 bits, float16 on CUDA: exact) and 512 bytes. It was float16 at any
    width: dot products above 2048 rounded to even numbers, so 4096-bit distances were off by up to 2
    and matches changed (checked below on these same descriptors: they do reach such dot products)."""
    from geofeat.matching import FP16_EXACT_BITS, _finish_matches, _hamming_dot_dtype, _hamming_search_torch

    rng = np.random.default_rng(n_bytes + rotations)
    n0, n1 = 60, 70
    # bits set with probability 3/4, so that dot products of 4096 bits exceed 2048
    d0, d1 = ((rng.integers(0, 256, (n, rotations, n_bytes), dtype=np.uint8)
               | rng.integers(0, 256, (n, rotations, n_bytes), dtype=np.uint8)) for n in (n0, n1))
    d1[5] = d1[3]  # a tie between two targets
    d0[7, 0] = d1[11, rotations - 1]  # an exact match, in the last rotation
    v0, v1 = np.arange(n0) % 9 != 4, np.arange(n1) % 13 != 6
    f0, f1 = (geofeat.Features(np.zeros((len(d), 2)), d if rotations > 1 else d[:, 0], v)
              for d, v in ((d0, v0), (d1, v1)))
    dtype = _hamming_dot_dtype("cuda", 8 * n_bytes)
    assert (dtype == torch.float16) == (8 * n_bytes <= FP16_EXACT_BITS)
    t = [torch.from_numpy(x) for x in (d0, d1, v0, v1)]
    for mutual, ratio in ((False, None), (True, None), (True, 0.9)):
        ref = match(f0, f1, mutual=mutual, ratio=ratio)
        got = _finish_matches(*_hamming_search_torch(*t, mutual, "cpu", dtype=dtype), ratio=ratio, mutual=mutual)
        np.testing.assert_array_equal(got.matches0, ref.matches0)
        np.testing.assert_array_equal(got.distances0, ref.distances0)
    assert ref.matches0[7] == 11 and ref.distances0[7] == 0
    half = _finish_matches(*_hamming_search_torch(*t, False, "cpu", dtype=torch.float16), ratio=None, mutual=False)
    plain = match(f0, f1)
    if 8 * n_bytes > FP16_EXACT_BITS:  # the float16 product the GPU ran before: distances rounded
        assert (half.distances0[v0] != plain.distances0[v0]).any()
    else:
        np.testing.assert_array_equal(half.distances0, plain.distances0)


@pytest.mark.skipif(CUDA, reason="checks the error without a GPU")
def test_cuda_requests_fail_clearly_without_gpu(pair):
    frame, kps = pair[0]
    with pytest.raises(RuntimeError, match="CUDA"):
        geofeat.extract(frame, 64, detector="sift", device="cuda")
    with pytest.raises(RuntimeError, match="CUDA"):
        match_cuda(GeoBit().compute(frame, kps[:8]), GeoBit().compute(frame, kps[:8]))
    with pytest.raises(ValueError, match="GeoPatch"):
        geofeat.extract(frame, 64, detector="sift", descriptor="geobit", device="cuda")
    from geofeat.geodesic.mesh import frame_mesh

    with pytest.raises(ValueError, match="device"):  # a typo is not the host mesh
        frame_mesh(frame, device="gpu")
    with pytest.raises(RuntimeError, match="CUDA"):
        frame_mesh(frame, device="cuda")


@pytest.mark.skipif(CUDA, reason="checks the error without a GPU")
def test_extract_on_cuda_takes_depth_config_none_as_the_cpu_path_does(pair, monkeypatch):
    """extract(..., depth_config=None): the CPU path takes it for GeoPatch's default ("auto",
    `make_descriptor` drops None); device="cuda" refused it ("depth_config: expected one of auto, ...").
    In the simulator's setting (which passes `require_cuda`) and without a GPU, it now gets as far as
    depth_config="auto" does: GeoPatch's network finds no CUDA GPU."""
    frame, _ = pair[0]
    assert len(geofeat.extract(frame, 16, detector="sift", depth_config=None)) == 16
    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    for depth_config in ("auto", None):
        with pytest.raises(RuntimeError, match="CUDA"):
            geofeat.extract(frame, 16, detector="sift", depth_config=depth_config, device="cuda")


@pytest.mark.skipif(CUDA, reason="checks the error without a GPU")
def test_torch_devices_fail_clearly_without_gpu():
    """GeoPatch's network and match(device=...) on a CUDA device without a GPU: the same RuntimeError
    as extract's (torch's own is "AssertionError: Torch not compiled with CUDA enabled"); a device
    name torch does not know is a ValueError naming `device`."""
    d = np.random.default_rng(0).standard_normal((4, 8)).astype(np.float32)
    for call in (partial(GeoPatch, device="cuda", backend="torch"), partial(match, d, d, device="cuda:0")):
        with pytest.raises(RuntimeError, match="no CUDA GPU is available"):
            call()
    for call in (partial(GeoPatch, device="tpu", backend="torch"), partial(match, d, d, device="tpu")):
        with pytest.raises(ValueError, match="device: expected"):
            call()
    assert match(d, d, device="cpu").matches0.tolist() == [0, 1, 2, 3]


@pytest.mark.skipif(CUDA, reason="checks the error without a GPU")
def test_a_falsy_device_is_not_read_as_the_cpu():
    """GeoPatch(device=0) (torch's cuda:0) or device="" ran the network on the CPU without a word
    (`device or "cpu"`); match(device=0) already refused it. Both now refuse it alike."""
    d = np.ones((2, 4), np.float32)
    for device in (0, ""):
        for call in (partial(GeoPatch, device=device), partial(match, d, d, device=device)):
            with pytest.raises(ValueError, match="device: expected"):
                call()


@pytest.mark.parametrize("device", ["meta", "mps", "xpu", torch.device("meta")])
def test_a_device_type_geofeat_does_not_run_on_is_a_value_error(device):
    """A torch device of another type than cpu or cuda passed `torch_device` and failed later in torch
    ("Cannot copy out of meta tensor", "Torch not compiled with XPU enabled", an AssertionError, with
    no word of `device`); now one ValueError naming it, from GeoPatch and from match alike."""
    d = np.ones((2, 4), np.float32)
    for call in (partial(GeoPatch, device=device, backend="torch"), partial(match, d, d, device=device)):
        with pytest.raises(ValueError, match="device: expected .*CPU and CUDA"):
            call()


@pytest.mark.skipif(not CUDA, reason="no CUDA GPU")
def test_gpu_mesh_equals_cpu_mesh(pair):
    """`build_mesh_cuda` on the GPU against the host mesh, on the Kinect pair (its "kinect" profile
    smooths the depth): the same faces but for a stated few (float32 smoothing), points within one
    float32 ulp, walk tables close."""
    from geofeat.geodesic.mesh import build_mesh
    from geofeat.gpu import build_mesh_cuda

    for frame, _ in pair:
        ref = build_mesh(frame, "auto")
        got = build_mesh_cuda(frame, "auto").to_host()
        assert (got.face_ok != ref.face_ok).mean() <= 1e-4
        np.testing.assert_allclose(got.points, ref.points, rtol=0, atol=5e-7, equal_nan=True)
        both = got.face_ok & ref.face_ok
        assert np.abs(got.walk_tables[0] - ref.walk_tables[0])[both].max() <= 1e-5


@pytest.mark.skipif(not CUDA, reason="no CUDA GPU")
def test_an_explicit_device_index_gives_the_same_patches(pair):
    """device="cuda:N" runs numba's kernels in that GPU's context (`gpu._numba_on`): on the last GPU
    torch sees, the patches equal those of the default device, bit for bit."""
    import torch

    from geofeat.gpu import polar_patches_cuda

    frame, kps = pair[0]
    last = f"cuda:{torch.cuda.device_count() - 1}"
    ref = polar_patches_cuda(frame, kps.xy[:256]).to_host()
    got = polar_patches_cuda(frame, kps.xy[:256], device=last).to_host()
    np.testing.assert_array_equal(got.valid, ref.valid)
    np.testing.assert_array_equal(got.coords, ref.coords)
    np.testing.assert_array_equal(got.values, ref.values)


@pytest.mark.skipif(not CUDA, reason="no CUDA GPU")
def test_gpu_path_equals_cpu_path(pair):
    """On a real GPU, float64 arithmetic differs from the CPU's in the last bits (fused multiply-adds,
    libdevice's cos/sin), so a ray that grazes a mesh vertex may take the other face: the tolerances
    hold for all but a stated small fraction of rays (the simulator tests hold them for all).

    First with the host's mesh uploaded (the walk, sampling and CNN alone), then with the mesh built
    on the GPU (the default): its depth smoothing is within two float32 ulp of OpenCV's, which moves
    samples by a few thousandths of a pixel (measured on an H200: 99.9 % within 5.2e-4 px, all within
    0.031 px; descriptors within 2.5e-4; the same mutual matches)."""
    from geofeat.geodesic.mesh import frame_mesh
    from geofeat.gpu import polar_patches_cuda

    net_gpu = GeoPatch(device="cuda", backend="torch")
    net_cpu = GeoPatch(device="cpu", backend="torch")
    feats_g, feats_c, feats_d = [], [], []
    for frame, kps in pair:
        host_mesh = frame_mesh(frame)
        cpu = geofeat.polar_patches(frame, kps)
        gpu = polar_patches_cuda(frame, kps, mesh=host_mesh).to_host()
        assert (gpu.valid != cpu.valid).sum() <= 1
        assert (gpu.rings_reached == cpu.rings_reached).mean() >= 0.999
        both = gpu.valid & cpu.valid
        d = np.abs(gpu.coords - cpu.coords)[both].max(-1)  # (M, R, A) px
        close = d < 1e-4
        assert close.mean() >= 0.999
        np.testing.assert_allclose(gpu.values[both][close], cpu.values[both][close], rtol=0, atol=1e-5)
        fg = net_gpu.compute_cuda(frame, kps, mesh=host_mesh)
        fc = net_cpu.compute(frame, kps)
        same = np.zeros(len(kps), bool)
        same[np.flatnonzero(both)[close.all((1, 2))]] = True
        assert same.mean() >= 0.95
        np.testing.assert_allclose(fg.descriptors.cpu().numpy()[same], fc.descriptors[same], rtol=0, atol=1e-4)
        feats_g.append(fg)
        feats_c.append(fc)
        # the mesh built on the GPU
        dev = polar_patches_cuda(frame, kps).to_host()
        assert (dev.valid != cpu.valid).sum() <= 1
        assert (dev.rings_reached == cpu.rings_reached).mean() >= 0.999
        both = dev.valid & cpu.valid
        d = np.abs(dev.coords - cpu.coords)[both].max(-1)
        assert np.quantile(d, 0.999) < 2e-3 and np.quantile(d, 0.5) < 1e-4
        fd = net_gpu.compute_cuda(frame, kps)
        err = np.abs(fd.descriptors.cpu().numpy() - fc.descriptors).max(1)
        assert np.quantile(err, 0.99) < 1e-4 and err.max() < 1e-2
        feats_d.append(fd)
    agree = match_cuda(feats_d[0], feats_d[1], mutual=True).matches0 == match(feats_c[0], feats_c[1], mutual=True).matches0
    assert agree.mean() >= 0.99
    ref = match(feats_c[0], feats_c[1], mutual=True)
    got = match_cuda(feats_g[0], feats_g[1], mutual=True)
    assert (got.matches0 == ref.matches0).mean() >= 0.99
    # the same descriptors give identical matches on both devices
    h0, h1 = feats_g[0].to_host(), feats_g[1].to_host()
    np.testing.assert_array_equal(match(h0, h1, mutual=True, device="cuda").matches0, match(h0, h1, mutual=True).matches0)
    np.testing.assert_array_equal(match_cuda(feats_g[0], feats_g[1], ratio=0.9).matches0, match(h0, h1, ratio=0.9).matches0)
    gb = GeoBit()
    b0, b1 = (gb.compute(f, k) for f, k in pair)
    np.testing.assert_array_equal(match_cuda(b0, b1, mutual=True).matches0, match(b0, b1, mutual=True).matches0)
    host = geofeat.extract(pair[0][0], 256, detector="sift", device="cuda")
    assert host.descriptors.shape == (256, 128) and isinstance(host.descriptors, np.ndarray)


def test_require_cuda_refuses_a_device_that_is_not_cuda():
    """The GPU path asked for "cpu" or an unknown name: one ValueError naming `device` (without a GPU
    it was "no CUDA GPU ... use device='cpu'" for device='cpu'; with one, "cpu" passed and the walk
    failed inside numba)."""
    from geofeat.gpu import mesh_device, require_cuda

    for device in ("cpu", "tpu"):
        for call in (require_cuda, mesh_device):
            with pytest.raises(ValueError, match="device"):
                call(device)


def test_match_cuda_checks_its_features(monkeypatch):
    """`match_cuda` on CPU tensors (the simulator's setting, which it reads when called) refuses what
    `geofeat.match` refuses: descriptors of different kinds (float against uint8 of the same width
    were compared as L2 numbers), NaN at a valid keypoint (one in features1 made every match -1),
    valid flags of another length (a torch broadcasting error)."""
    from geofeat.features import Features

    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    rng = np.random.default_rng(0)
    d = rng.standard_normal((6, 32)).astype(np.float32)
    f = Features(np.zeros((6, 2)), d, np.ones(6, bool))
    assert match_cuda(f, f).matches0.tolist() == list(range(6))
    bits = Features(np.zeros((6, 2)), rng.integers(0, 256, (6, 32), dtype=np.uint8), np.ones(6, bool))
    for a, b in ((f, bits), (bits, f)):
        with pytest.raises(ValueError, match="different kinds"):
            match_cuda(a, b)
    nan = d.copy()
    nan[2, 5] = np.nan
    with pytest.raises(ValueError, match="features1 has NaN"):
        match_cuda(f, Features(np.zeros((6, 2)), nan, np.ones(6, bool)), mutual=True)
    huge = d * np.float32(1e19)  # squared distances past float32: inf, and no keypoint matched, without a word
    with pytest.raises(ValueError, match="features1 has a row of squared norm .*overflow"):
        match_cuda(f, Features(np.zeros((6, 2)), huge, np.ones(6, bool)))
    large = Features(np.zeros((6, 2)), d * np.float32(1e15), np.ones(6, bool))  # within float32's range
    assert match_cuda(large, large).matches0.tolist() == list(range(6))
    masked = Features(np.zeros((6, 2)), nan, np.arange(6) != 2)  # NaN at an invalid keypoint is fine
    got = match_cuda(f, masked).matches0
    assert 2 not in got.tolist() and got.tolist() == match(f, masked).matches0.tolist()
    for bad in (dict(ratio=True), dict(ratio=1.5), dict(ratio="0.8"), dict(mutual="no"), dict(mutual=1)):
        with pytest.raises(ValueError, match="ratio|mutual"):  # as geofeat.match refuses them
            match(f, f, **bad)
        with pytest.raises(ValueError, match="ratio|mutual"):
            match_cuda(f, f, **bad)
    short = torch.ones(4, dtype=torch.bool)
    with pytest.raises(ValueError, match="features0: expected"):
        match_cuda(type("F", (), {"descriptors": torch.from_numpy(d), "valid": short})(), f)
    with pytest.raises(TypeError, match="features0"):
        match_cuda(d, f)


def test_match_cuda_refuses_float_descriptors_of_three_dimensions(monkeypatch):
    """Float (N, R, D) descriptors: `geofeat.match` refuses them (L2 takes (N, D)); `match_cuda` ran
    them through its matrix product as a batch and returned N * R * D "matches" for N keypoints, or
    failed in torch's broadcasting. On CPU tensors, in the simulator's setting."""
    from geofeat.features import Features

    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    rng = np.random.default_rng(0)
    for shape in ((4, 4, 4), (4, 1, 4), (5, 3, 8)):
        f = Features(np.zeros((shape[0], 2)), rng.standard_normal(shape).astype(np.float32), np.ones(shape[0], bool))
        with pytest.raises(ValueError, match=r"expects \(N, D\)"):
            match(f, f)
        with pytest.raises(ValueError, match=r"expects \(N, D\)"):
            match_cuda(f, f)


def test_compute_cuda_refuses_what_is_not_a_frame_as_compute_does(monkeypatch):
    """`compute_cuda` given None or a dict for the frame: the CPU's `GeoPatch.compute` says "frame:
    expected an RGBDFrame"; the GPU path failed with "AttributeError: 'NoneType' object has no
    attribute 'shape'". Checked before any kernel (the simulator's setting, CPU tensors)."""
    from geofeat.gpu import compute_cuda

    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    net = GeoPatch(device="cpu", backend="torch")
    for frame in (None, {"depth": 1.0}):
        for call in (net.compute, partial(compute_cuda, net)):
            with pytest.raises(TypeError, match="frame: expected an RGBDFrame"):
                call(frame, [[5.0, 5.0]])


def test_match_cuda_refuses_features_whose_keypoints_do_not_fit_their_descriptors(monkeypatch):
    """Features whose keypoints were replaced by fewer after construction: `geofeat.match` refuses
    them; `match_cuda` matched to rows that have no keypoint (matches0 indices past the keypoints).
    On CPU tensors, in the simulator's setting."""
    from geofeat.features import Features

    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    d = np.random.default_rng(0).standard_normal((6, 8)).astype(np.float32)
    f, g = (Features(np.zeros((6, 2)), d, np.ones(6, bool)) for _ in range(2))
    g.keypoints = np.zeros((4, 2))
    for a, b, which in ((f, g, "features1"), (g, f, "features0")):
        for call in (match, match_cuda):
            with pytest.raises(ValueError, match=f"{which}: keypoints, descriptors and valid must have one entry"):
                call(a, b)
    assert match_cuda(f, f).matches0.tolist() == list(range(6))


def test_a_device_mesh_of_another_frame_is_refused(pair, monkeypatch):
    """`polar_patches(frame, kps, mesh=...)` refuses a mesh built from another frame of the same size
    (its `source` fingerprint differs); `polar_patches_cuda` took a `DeviceMesh` of another frame
    (the frame rolled by 180 degrees, say) without a word, the patches walked on the wrong surface.
    A DeviceMesh now carries its frame's fingerprint as GridMesh does (`build_mesh_cuda` sets it: tested
    in the simulator, tests/test_walk_cuda.py). On CPU tensors in the simulator's setting: the check
    comes before any kernel."""
    from geofeat.geodesic.mesh import frame_fingerprint
    from geofeat.gpu import DeviceMesh, polar_patches_cuda

    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    frame, kps = pair[0]
    other = frame.rotated90(2)  # the same size, another depth
    assert other.shape == frame.shape
    mesh = DeviceMesh((), (), frame.K, (0.5, 0.5), frame.shape, torch.device("cpu"), frame_fingerprint(other))
    with pytest.raises(ValueError, match="mesh: built from another frame"):
        polar_patches_cuda(frame, kps[:4], mesh=mesh)


def test_polar_patches_cuda_checks_blur_as_the_cpu_does(pair, monkeypatch):
    """A sampling blur outside 0-20 px: the CPU's `polar_patches` refuses it; `polar_patches_cuda`
    ran a negative one as no blur and a larger one as asked. Checked before any kernel (the
    simulator's setting, CPU tensors)."""
    from geofeat.gpu import polar_patches_cuda

    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    frame, kps = pair[0]
    for blur in (-1.0, 25.0, True):
        for call in (geofeat.polar_patches, polar_patches_cuda):
            with pytest.raises(ValueError, match="blur_px"):
                call(frame, kps[:4], blur_px=blur)


def test_a_cuda_index_torch_does_not_see_is_a_value_error(monkeypatch):
    """device='cuda:7' on a machine with one GPU passed the checks and failed later in torch with
    "CUDA error: invalid device ordinal"; now one ValueError naming the device and the GPUs there are.
    (torch.cuda is faked to report one GPU, so this runs without one.)"""
    from geofeat.gpu import torch_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert torch_device("cuda:0") == torch.device("cuda", 0)
    assert torch_device("cuda") == torch.device("cuda")
    for device in ("cuda:7", "cuda:1", torch.device("cuda", 1)):
        with pytest.raises(ValueError, match="device: .*cuda:[17].*1 CUDA GPU"):
            torch_device(device)


def test_device_records_print_a_summary_not_their_tensors(pair):
    """DevicePatches, DeviceFeatures and DeviceMesh print one line (on CPU tensors here); the
    dataclasses' reprs dumped every tensor."""
    from geofeat.gpu import DeviceFeatures, DeviceMesh, DevicePatches

    frame, kps = pair[0]
    p = geofeat.polar_patches(frame, kps)
    dp = DevicePatches(p.keypoints, torch.from_numpy(p.values), torch.from_numpy(p.coords), torch.from_numpy(p.valid),
                       torch.from_numpy(p.rings_reached), torch.from_numpy(p.points), p.radius)
    df = DeviceFeatures(p.keypoints, torch.zeros((len(p), 128)), torch.from_numpy(p.valid))
    dm = DeviceMesh((torch.zeros((240, 320, 3)),), (), frame.K, (0.5, 0.5), frame.shape, torch.device("cpu"))
    texts = [repr(x) for x in (dp, df, dm)]
    assert all("\n" not in t and "tensor(" not in t and len(t) < 160 for t in texts), texts
    assert f"{len(p)} keypoints" in texts[0] and "32 rings x 32 angles" in texts[0]
    assert "descriptors (" in texts[1] and "torch.float32" in texts[1]
    assert texts[2].startswith("DeviceMesh(320x240 grid for a 640x480 frame")
