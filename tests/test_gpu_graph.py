"""`geofeat.gpu_graph.FrameGraph`: a stream of frames of one camera replayed as one CUDA graph per
frame, against `gpu.compute_cuda` + `gpu.match_cuda` on the same frames.

Without a GPU the FrameGraph runs its device code eagerly in numba's CUDA simulator (a subprocess, so
that the simulator does not leak into other tests): padding, the reference search, the checks. With
a GPU, the graph's replays are compared with the eager path on the shipped Kinect frame.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from cuda_simulator import run_simulated

SIM_SCRIPT = r'''
import cv2, numpy as np
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.features import Features
from geofeat.frame import RGBDFrame
from geofeat.gpu import compute_cuda, match_cuda, simulated
from geofeat.gpu_graph import FrameGraph
assert simulated()
H, W = 48, 56
K = np.array([[300.0, 0, 27.5], [0, 300.0, 23.5], [0, 0, 1]])
v, u = np.mgrid[0:H, 0:W].astype(float)
rng = np.random.default_rng(3)

def frame(phase):
    """A bumpy sheet with a hole; `phase` moves its bumps and texture (another frame of the stream)."""
    depth = (1.0 + 0.04 * np.sin(u / 5.0 + phase) * np.cos(v / 6.0) + 0.002 * u).astype(np.float32)
    depth[30:33, 8:12] = 0  # a small hole: filled on the host before the upload
    img = cv2.GaussianBlur(np.random.default_rng(int(10 * phase)).random((H, W)).astype(np.float32), (0, 0), 1.5)
    return RGBDFrame((img - img.min()) / (img.max() - img.min()), depth, K)

kps = [np.array([[28.2, 24.3], [20.7, 17.1], [31.4, 26.6], [1.5, 1.5], [35.1, 20.2]]),
       np.array([[27.8, 23.9], [21.1, 17.4], [30.9, 27.1]]),
       np.array([[25.0, 22.0]])]
from geofeat.depth import depth_profile
net = GeoPatch(device="cpu", backend="torch", depth_config="auto")
f0 = frame(0.0)
profile = depth_profile(f0)  # the FrameGraph measures the stream's profile once, on `like`
assert {depth_profile(frame(p)) for p in (0.3, 0.6)} == {profile}
ref_net = GeoPatch(device="cpu", backend="torch", depth_config=profile)
reference = compute_cuda(ref_net, f0, kps[0])
graph = FrameGraph(net, f0, n=6, reference=reference)
assert "eager" in repr(graph) and "up to 6 keypoints" in repr(graph)
for phase, k in ((0.3, kps[1]), (0.0, kps[0]), (0.6, kps[2])):
    f = frame(phase)
    want = compute_cuda(ref_net, f, k)
    for mutual, ratio in ((False, None), (True, None), (False, 0.9)):
        got, matches = graph.match(f, k, mutual=mutual, ratio=ratio)
        assert len(got) == len(k) and got.descriptors.shape == (len(k), 128)
        np.testing.assert_allclose(got.descriptors.numpy(), want.descriptors.numpy(), rtol=0, atol=1e-6)
        np.testing.assert_array_equal(got.valid.numpy(), want.valid.numpy())
        expect = match_cuda(reference, want, mutual=mutual, ratio=ratio)
        np.testing.assert_array_equal(matches.matches0, expect.matches0)
        np.testing.assert_allclose(matches.distances0, expect.distances0, rtol=1e-6, atol=1e-6)
    assert not graph._out["valid"].numpy()[len(k):].any()  # the padding is never valid
    if phase == 0.0:  # the reference frame against itself: every valid keypoint finds itself
        ok = want.valid.numpy()
        assert ok.sum() >= 3 and (matches.matches0[ok] == np.flatnonzero(ok)).all()
# a frame without a reference, the features alone
plain = FrameGraph(net, f0, n=5)
np.testing.assert_allclose(plain.compute(f0, kps[0]).descriptors.numpy(), reference.descriptors.numpy(), rtol=0,
                           atol=1e-6)
for bad, message in ((lambda: plain.match(f0, kps[0]), "no reference"),
                     (lambda: graph.compute(f0.rotated90(1), kps[1]), "holds 56x48 frames"),
                     (lambda: graph.compute(RGBDFrame(f0.image, f0.depth, K * [[1.01], [1], [1]]), kps[1]), "intrinsics"),
                     (lambda: graph.compute(f0, np.zeros((7, 2)) + 5), "at most n=6"),
                     (lambda: graph.compute(f0, np.array([[60.0, 5.0]])), "keypoints"),
                     (lambda: graph.compute(f0, np.zeros((0, 2))), "empty"),
                     (lambda: FrameGraph(net, f0, n=0), "n: expected"),
                     (lambda: FrameGraph(net, f0, reference=Features(np.zeros((2, 2)), np.zeros((2, 64), np.float32),
                                                                      np.ones(2, bool))), "reference"),
                     (lambda: FrameGraph(net, f0, reference=Features(np.zeros((1, 2)),
                                                                      np.full((1, 128), np.nan, np.float32),
                                                                      np.ones(1, bool))), "NaN")):
    try:
        bad()
        raise AssertionError(f"accepted: {message}")
    except ValueError as exc:
        assert message in str(exc), (message, str(exc))
print("ok")
'''


def test_frame_graph_equals_compute_and_match_in_cuda_simulator():
    """Three frames of a stream through one FrameGraph (eager under the simulator): descriptors equal
    `compute_cuda`'s with the profile measured once on `like`, matches against the reference equal
    `match_cuda`'s for plain, mutual and ratio matching, with fewer keypoints than `n` (padding); and a frame of another size or camera, too many keypoints, a reference of the wrong
    width or with NaN, and no keypoints (as `compute_cuda` refuses them) are refused with a message naming them."""
    run_simulated(SIM_SCRIPT)


def _cuda() -> bool:
    try:
        import torch
        from numba import cuda

        return torch.cuda.is_available() and bool(cuda.is_available()) and not os.environ.get("NUMBA_ENABLE_CUDASIM")
    except Exception:
        return False


@pytest.mark.skipif(not _cuda(), reason="no CUDA GPU")
def test_frame_graph_replays_equal_the_eager_path_on_device():
    """On a GPU: the graph's replays give the eager GPU path's descriptors and matches (fp32 and fp16
    CNN), frame after frame: identical with `n` keypoints, within 5e-4 and 99 % of the matches with
    fewer (the CNN then runs on the padded batch, for which cuDNN may pick other algorithms)."""
    import geofeat
    from geofeat.depth import depth_profile
    from geofeat.descriptors.geopatch import GeoPatch
    from geofeat.frame import RGBDFrame
    from geofeat.gpu import compute_cuda, match_cuda
    from geofeat.gpu_graph import FrameGraph

    f0 = geofeat.read_demo_frame()
    profile = depth_profile(f0)
    net = GeoPatch(device="cuda", backend="torch", depth_config=profile)
    k0 = geofeat.detect(f0, 1024, detector="sift")
    for half in (False, True):
        reference = compute_cuda(net, f0, k0, half=half)
        graph = FrameGraph(net, f0, n=1024, reference=reference, half=half)
        assert "CUDA graph" in repr(graph)
        for step, shift in enumerate((0, 3, 7)):
            f = RGBDFrame(f0.color, np.roll(f0.depth, shift, axis=1), f0.K)  # another depth each frame
            k = k0[: 1024 - 100 * step]
            got, matches = graph.match(f, k, mutual=True)
            want = compute_cuda(net, f, k, half=half)
            err = float((got.descriptors - want.descriptors).abs().max())
            agree = float((matches.matches0 == match_cuda(reference, want, mutual=True).matches0).mean())
            print(f"half={half} keypoints={len(k)}: descriptors max difference {err:.2e}, matches agree {agree:.4f}")
            # the same batch: the same kernels, the same numbers; a padded batch may get other
            # convolution algorithms from cuDNN (measured on an H100: 1.7e-4 at 924 of 1024)
            assert err <= (1e-6 if len(k) == graph.n else 5e-4)
            np.testing.assert_array_equal(got.valid.cpu().numpy(), want.valid.cpu().numpy())
            assert agree >= (1.0 if len(k) == graph.n else 0.99)



def _frame_script(body: str) -> str:
    return r"""
import cv2, numpy as np, torch
from geofeat.depth import filled_depth, resolve_depth_config
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.features import Features
from geofeat.frame import RGBDFrame
from geofeat.gpu import build_mesh_cuda, mesh_from_depth, simulated
from geofeat.gpu_graph import FrameGraph
assert simulated()

def frame(H, W, f=300.0):
    v, u = np.mgrid[0:H, 0:W].astype(float)
    depth = (1.0 + 0.04 * np.sin(u / 5.0) * np.cos(v / 6.0) + 0.002 * u).astype(np.float32)
    img = cv2.GaussianBlur(np.random.default_rng(0).random((H, W)).astype(np.float32), (0, 0), 1.5)
    return RGBDFrame(img, depth, np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]]))
""" + body + "\nprint('ok')\n"


def test_mesh_from_depth_into_a_mesh_of_another_frame_size_in_cuda_simulator():
    """`gpu.mesh_from_depth(..., out=mesh)` for a frame of another size and camera whose mesh grid has
    the same size (49x57 and 48x56 both halve to 24x28) gives the fresh mesh's scale, frame size and
    intrinsics: it kept the old mesh's, so that the walk's starts (`image_to_mesh`) came from the
    wrong scale and `polar_patches_cuda` checked the frame against the wrong size."""
    run_simulated(_frame_script(r"""
config = resolve_depth_config("quantised")
small, large = frame(48, 56), frame(49, 57, f=330.0)
want = build_mesh_cuda(large, config)
out = build_mesh_cuda(small, config)
assert out.tensors[0].shape == want.tensors[0].shape
got = mesh_from_depth(torch.from_numpy(filled_depth(large.depth, config)), config, large.K, out=out)
assert got.image_shape == want.image_shape, (got.image_shape, want.image_shape)
assert got.scale == want.scale, (got.scale, want.scale)
np.testing.assert_array_equal(got.K, want.K)
xy = np.array([[30.0, 20.0]])
np.testing.assert_array_equal(got.image_to_mesh(xy), want.image_to_mesh(xy))
"""))


def test_a_reference_without_keypoints_is_refused_in_cuda_simulator():
    """A FrameGraph with a reference of no keypoints: refused with a ValueError naming `reference`
    (it was built, and every frame then failed inside the search: torch's argmin over no rows)."""
    run_simulated(_frame_script(r"""
small = frame(48, 56)
net = GeoPatch(device="cpu", backend="torch", depth_config="quantised")
empty = Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32), np.zeros(0, bool))
try:
    FrameGraph(net, small, n=4, reference=empty).compute(small, [[20.0, 20.0]])
    raise AssertionError("accepted an empty reference")
except ValueError as exc:
    assert "reference" in str(exc), str(exc)
"""))


def test_a_frame_whose_depth_was_edited_in_place_is_checked_in_cuda_simulator():
    """A frame whose depth was rewritten in place in millimetres (a stream that reuses one RGBDFrame):
    `compute_cuda` (through `frame_mesh`) and the CPU path refuse it, naming the millimetres; the
    FrameGraph walked a surface a thousand times too far without a word."""
    run_simulated(_frame_script(r"""
small = frame(48, 56)
net = GeoPatch(device="cpu", backend="torch", depth_config="quantised")
graph = FrameGraph(net, small, n=2)
edited = frame(48, 56)
edited.depth.flags.writeable = True  # a frame is read-only: edited in place only after turning that off
edited.depth[:] *= 1000.0
try:
    graph.compute(edited, [[20.0, 20.0]])
    raise AssertionError("accepted millimetre depth")
except ValueError as exc:
    assert "millimetres" in str(exc), str(exc)
"""))
