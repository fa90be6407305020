"""The GPU walk (`geofeat.geodesic.walk_cuda`, the walk's kernel source compiled by numba.cuda)
against the CPU walk (the same source compiled by numba.njit).

Without a GPU the kernel runs in numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1), in a subprocess so
that the simulator does not leak into other tests. On a machine with a CUDA GPU (and numba's CUDA
target) the same comparison also runs on the real device.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cuda_simulator import SMALL_FRAME, run_simulated

#: Tolerances of GPU against CPU. In the simulator the device functions run as Python on the same
#: float64 operations as the njit build (math.sqrt/cos/sin are the same libm calls), so the results
#: agree to float32 rounding of the stored samples. On a real GPU, cos/sin come from libdevice and
#: the compiler may fuse multiply-adds, so positions may differ by a few ulp of float64 before the
#: float32 store: the same tolerance holds for all but rays that graze a vertex.
COORD_TOL_PX = 1e-4
POINT_TOL_M = 1e-6

SCRIPT = r'''
import json, sys
import numpy as np
from geofeat.geodesic.mesh import mesh_from_points
from geofeat.geodesic.walk import MAX_CROSSINGS, walk_polar

def scene():
    """A 20x20 bumpy surface with a hole and a depth step: rays cross many faces, some stop."""
    H = W = 20
    K = np.array([[30.0, 0.0, 9.5], [0.0, 30.0, 9.5], [0.0, 0.0, 1.0]])
    v, u = np.mgrid[0:H, 0:W].astype(float)
    z = 1.0 + 0.04 * np.sin(u / 3.0) * np.cos(v / 4.0) + 0.01 * u
    z[14:17, 3:6] = np.nan  # a hole
    z[:, 17:] += 0.3  # a depth discontinuity
    pts = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=-1)
    mesh = mesh_from_points(pts, K, (1.0, 1.0), (H, W))
    starts = np.array([[9.3, 9.1], [4.2, 13.4], [15.6, 4.3], [16.4, 10.2], [4.5, 15.5], [0.2, 0.3]])
    return mesh, starts, K

mesh, starts, K = scene()
local, edges = mesh.walk_tables
args = (mesh.points, mesh.face_ok, mesh.normals, local, edges, starts, K, 0.12, 8, 6, MAX_CROSSINGS)
cpu = walk_polar(*args)

from numba import cuda
from geofeat.geodesic.walk_cuda import walk_polar_cuda
dev = [cuda.to_device(np.ascontiguousarray(a)) for a in args[:7]]
gpu = walk_polar_cuda(*dev, *args[7:])
gpu = [g.copy_to_host() for g in gpu]
out = {}
for name, c, g in zip(("samples", "coords", "reached", "centre"), cpu, gpu):
    np.save(sys.argv[1] + f"/{name}_cpu.npy", c)
    np.save(sys.argv[1] + f"/{name}_gpu.npy", g)
print(json.dumps({"simulator": bool(cuda.simulator_initialized if hasattr(cuda, "simulator_initialized") else False)}))
'''


def _run(tmp_path: Path, simulate: bool) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    env = dict(os.environ)
    env.pop("NUMBA_ENABLE_CUDASIM", None)
    if simulate:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    src = str(Path(__file__).resolve().parents[1] / "src")
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path)], env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {name: (np.load(tmp_path / f"{name}_cpu.npy"), np.load(tmp_path / f"{name}_gpu.npy"))
            for name in ("samples", "coords", "reached", "centre")}


def _check(res) -> None:
    samples_c, samples_g = res["samples"]
    coords_c, coords_g = res["coords"]
    reached_c, reached_g = res["reached"]
    centre_c, centre_g = res["centre"]
    # the scene exercises every case: full rays, rays stopped by the hole / step / border, and a
    # keypoint without surface
    assert (reached_c == 6).any() and ((reached_c > 0) & (reached_c < 6)).any()
    assert np.isnan(centre_c).any() and np.isfinite(centre_c).any()
    np.testing.assert_array_equal(reached_g, reached_c)
    np.testing.assert_array_equal(np.isnan(coords_g), np.isnan(coords_c))
    np.testing.assert_allclose(centre_g, centre_c, rtol=0, atol=1e-12, equal_nan=True)
    np.testing.assert_allclose(coords_g, coords_c, rtol=0, atol=COORD_TOL_PX, equal_nan=True)
    np.testing.assert_allclose(samples_g, samples_c, rtol=0, atol=POINT_TOL_M, equal_nan=True)


def test_gpu_walk_equals_cpu_walk_in_cuda_simulator(tmp_path):
    res = _run(tmp_path, simulate=True)
    _check(res)
    # in the simulator the same float64 operations run: equal to the float32 rounding of the store
    for name in ("samples", "coords"):
        c, g = res[name]
        assert np.nanmax(np.abs(c.astype(np.float64) - g)) <= 1e-5


E2E_SCRIPT = SMALL_FRAME + r'''
import geofeat
from geofeat.descriptors.geobit import GeoBit
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.gpu import compute_cuda, match_cuda, polar_patches_cuda, simulated
from geofeat.matching import match
assert simulated()
kps = [np.array([[24.2, 20.3], [20.7, 17.1], [27.4, 22.6], [2.5, 3.5]]),
       np.array([[23.8, 19.9], [21.1, 17.4], [26.9, 23.1], [30.2, 12.7]])]
net = GeoPatch(device="cpu", backend="torch", depth_config="clean")
gb = GeoBit(depth_config="clean")
fc, fg, bc, partial = [], [], [], []
for k in kps:
    cpu = geofeat.polar_patches(frame, k, depth_config="clean")
    gpu = polar_patches_cuda(frame, k, depth_config="clean").to_host()
    assert cpu.valid[:3].all()
    partial.append(bool((cpu.rings_reached < 32).any()))  # rays that leave the frame early
    np.testing.assert_array_equal(gpu.valid, cpu.valid)
    np.testing.assert_array_equal(gpu.rings_reached, cpu.rings_reached)
    np.testing.assert_allclose(gpu.coords, cpu.coords, rtol=0, atol=1e-5, equal_nan=True)
    np.testing.assert_allclose(gpu.values, cpu.values, rtol=0, atol=1e-6)
    fc.append(net.compute(frame, k))
    fg.append(compute_cuda(net, frame, k))
    np.testing.assert_allclose(fg[-1].descriptors.numpy(), fc[-1].descriptors, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(fg[-1].valid.numpy(), fc[-1].valid)
    bc.append(gb.compute(frame, k, patches=cpu))
for mutual in (False, True):
    np.testing.assert_array_equal(match_cuda(fg[0], fg[1], mutual=mutual).matches0,
                                  match(fc[0], fc[1], mutual=mutual).matches0)
    np.testing.assert_array_equal(match_cuda(bc[0], bc[1], mutual=mutual).matches0,
                                  match(bc[0], bc[1], mutual=mutual).matches0)
assert any(partial)
print("ok")
'''


def test_gpu_path_equals_cpu_path_in_cuda_simulator():
    """The whole `geofeat.gpu` path (walk kernel simulated, torch on CPU tensors) on a small frame:
    patches, descriptors and matches equal the CPU path's."""
    run_simulated(E2E_SCRIPT)


MESH_SCRIPT = r'''
import cv2, numpy as np
import geofeat
from geofeat.depth import PROFILES
from geofeat.frame import RGBDFrame
from geofeat.geodesic.mesh import build_mesh, frame_mesh
from geofeat.gpu import DeviceMesh, build_mesh_cuda, polar_patches_cuda, simulated
assert simulated()
H, W = 64, 80
K = np.array([[200.0, 0, 39.5], [0, 200.0, 31.5], [0, 0, 1]])
v, u = np.mgrid[0:H, 0:W].astype(float)
rng = np.random.default_rng(1)
depth = (1.0 + 0.05 * np.sin(u / 5.0) * np.cos(v / 6.0) + 0.002 * u
         + 0.002 * rng.standard_normal((H, W))).astype(np.float32)
depth[20:23, 30:34] = 0  # a small hole: filled
depth[:, 60:] += 0.4  # a depth step: no faces across it
depth[50:, :10] = 0  # a hole on the border: kept
img = cv2.GaussianBlur(rng.random((H, W)).astype(np.float32), (0, 0), 1.5)
frame = RGBDFrame((img - img.min()) / (img.max() - img.min()), depth, K)
for name, cfg in PROFILES.items():
    ref = build_mesh(frame, cfg)
    got = build_mesh_cuda(frame, cfg).to_host()
    assert 0.9 < ref.face_ok.mean() < 1.0
    np.testing.assert_array_equal(got.face_ok, ref.face_ok)
    np.testing.assert_allclose(got.K, ref.K, rtol=0, atol=1e-12)
    assert got.scale == ref.scale and got.image_shape == ref.image_shape
    # "clean" keeps the depth: bit-identical. "kinect" smooths it in float32 on the device, within
    # one float32 ulp of OpenCV's; the normals and tables follow within the surface's sensitivity
    tol = 0.0 if name == "clean" else 3e-7
    np.testing.assert_allclose(got.points, ref.points, rtol=0, atol=tol, equal_nan=True)
    for a, b in zip(got.walk_tables + (got.normals,), ref.walk_tables + (ref.normals,)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e3 * tol)
    kps = np.array([[40.2, 30.3], [20.7, 17.1], [47.4, 42.6], [30.5, 21.5], [58.5, 30.2]])
    cpu = geofeat.polar_patches(frame, kps, depth_config=name, radius=0.05)
    dev = polar_patches_cuda(frame, kps, depth_config=name, radius=0.05)  # builds the mesh on the device
    assert isinstance(frame_mesh(frame, name, device="cuda"), DeviceMesh)
    dev = dev.to_host()
    assert cpu.valid.sum() >= 4, (name, cpu.valid)  # "quantised" loses the patch nearest the depth step
    np.testing.assert_array_equal(dev.valid, cpu.valid)
    np.testing.assert_array_equal(dev.rings_reached, cpu.rings_reached)
    np.testing.assert_allclose(dev.coords, cpu.coords, rtol=0, atol=1e-4, equal_nan=True)
    np.testing.assert_allclose(dev.values, cpu.values, rtol=0, atol=1e-5)
m = frame_mesh(frame, "kinect", device="cuda")
assert frame_mesh(frame, "kinect", device="cuda") is m  # cached on the frame
from geofeat.geodesic.mesh import frame_fingerprint
assert m.source == frame_fingerprint(frame) and m.to_host().source == m.source
flipped = frame.rotated90(2)  # the same size, another depth: its mesh is refused, as on the CPU
try:
    polar_patches_cuda(flipped, kps[:1], mesh=m)
    raise AssertionError("a DeviceMesh of another frame was accepted")
except ValueError as exc:
    assert "another frame" in str(exc)
frame.depth.flags.writeable = True  # a frame is read-only: edited in place only after turning that off
frame.depth[10, 10] += 0.01
assert frame_mesh(frame, "kinect", device="cuda") is not m  # an edited depth is noticed
print("ok")
'''


def test_gpu_mesh_equals_cpu_mesh_in_cuda_simulator():
    """The fresh-frame part of the GPU path (`gpu.build_mesh_cuda`: smoothing pyramid on tensors,
    faces / normals / walk tables by the CPU's kernel sources, one thread per face) against the host
    mesh, with a filled hole, a kept border hole and a depth step, for both depth profiles; then the
    patches it gives against the CPU path's."""
    run_simulated(MESH_SCRIPT)


ODD_SCRIPT = r'''
import cv2, numpy as np
import geofeat
from geofeat.frame import RGBDFrame
from geofeat.geodesic.mesh import build_mesh
from geofeat.gpu import build_mesh_cuda, polar_patches_cuda, simulated
assert simulated()
H, W = 45, 59  # not multiples of 4: the "kinect" pyramid's resampling branch (depth.pyramid_resampling)
K = np.array([[260.0, 6.0, 29.0], [0, 190.0, 22.0], [0, 0, 1]])  # non-square pixels and a skew
v, u = np.mgrid[0:H, 0:W].astype(float)
rng = np.random.default_rng(2)
depth = (1.0 + 0.05 * np.sin(u / 5.0) * np.cos(v / 6.0) + 0.002 * u
         + 0.002 * rng.standard_normal((H, W))).astype(np.float32)
depth[:, 46:] += 0.4  # a depth step
depth[36:, :8] = 0  # a hole on the border
img = cv2.GaussianBlur(rng.random((H, W)).astype(np.float32), (0, 0), 1.5)
frame = RGBDFrame((img - img.min()) / (img.max() - img.min()), depth, K)
ref = build_mesh(frame, "kinect")
got = build_mesh_cuda(frame, "kinect").to_host()
np.testing.assert_array_equal(got.face_ok, ref.face_ok)
np.testing.assert_allclose(got.points, ref.points, rtol=0, atol=3e-7, equal_nan=True)
# the centre, the four corners, on the border hole, both sides of the step
kps = np.array([[29.2, 22.3], [0, 0], [W - 1, H - 1], [1.2, 1.3], [W - 2.2, H - 2.3], [3.0, 40.0], [9.0, 36.0],
                [44.5, 20.2], [47.6, 30.7]])
cpu = geofeat.polar_patches(frame, kps, depth_config="kinect", radius=0.06, n_angles=7, n_rings=5)
dev = polar_patches_cuda(frame, kps, depth_config="kinect", radius=0.06, n_angles=7, n_rings=5).to_host()
assert 3 <= cpu.valid.sum() < len(kps) and ((cpu.rings_reached > 0) & (cpu.rings_reached < 5)).any()
np.testing.assert_array_equal(dev.valid, cpu.valid)
np.testing.assert_array_equal(dev.rings_reached, cpu.rings_reached)
np.testing.assert_allclose(dev.coords, cpu.coords, rtol=0, atol=1e-4, equal_nan=True)
np.testing.assert_allclose(dev.values, cpu.values, rtol=0, atol=1e-5)
np.testing.assert_allclose(dev.points, cpu.points, rtol=0, atol=1e-6, equal_nan=True)
print("ok")
'''


def test_gpu_path_with_non_square_pixels_in_cuda_simulator():
    """Non-square pixels with a skew (the mesh's footprint is `depth.mean_focal`, the walk projects
    with the full K), a frame whose sides are not multiples of 4 (the pyramid's resampling branch),
    keypoints on and near the corners (rays leaving the mesh), on a border hole and beside a depth
    step: the GPU mesh, validity,
    rings reached, coordinates, values and points equal the CPU's (measured: coordinates within
    5e-6 px, most identical)."""
    run_simulated(ODD_SCRIPT)


def _real_gpu() -> bool:
    try:
        from numba import cuda

        return bool(cuda.is_available()) and not os.environ.get("NUMBA_ENABLE_CUDASIM")
    except Exception:
        return False


@pytest.mark.skipif(not _real_gpu(), reason="no CUDA GPU")
def test_gpu_walk_equals_cpu_walk_on_device(tmp_path):
    _check(_run(tmp_path, simulate=False))


def test_walk_cuda_not_imported_by_package():
    """`import geofeat` and the CPU walk work without numba.cuda: the GPU module loads on demand."""
    code = ("import sys, geofeat; geofeat.polar_patches; "
            "assert 'geofeat.geodesic.walk_cuda' not in sys.modules; assert 'numba.cuda' not in sys.modules")
    src = str(Path(__file__).resolve().parents[1] / "src")
    env = dict(os.environ, PYTHONPATH=src + os.pathsep + os.environ.get("PYTHONPATH", ""))
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=300)
