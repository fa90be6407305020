"""A stream of frames from one camera on the GPU, each frame one CUDA graph replay (`FrameGraph`).

On a GPU, a fresh frame of the GPU path (`geofeat.gpu`: mesh, walk, sampling, GeoPatch CNN, L2
match) is bound by its host: about a hundred small kernels, each launched from Python, take longer to
launch than to run (BENCHMARKS.md, "A fresh frame as one CUDA graph"). A `FrameGraph` records them
once into a CUDA graph with fixed buffers: the filled depth, the gray image, the walk's start points
and a keypoint mask (up to `n` keypoints; fewer are padded and marked invalid). Per frame the host
fills the depth's small holes (`depth.filled_depth`), copies these four inputs into pinned buffers
and replays the graph; `match` reads back only the matches.

The graph holds one frame size, one camera (intrinsics), one depth profile, at most `n` keypoints and
one reference to match against: a frame of another size or camera is refused (make a new
FrameGraph). The results are those of `gpu.compute_cuda` and `gpu.match_cuda` run on the same
frame with the same depth profile: the graph replays their own device code (`gpu.mesh_from_depth`,
`gpu.walk_and_sample`, `GeoPatch.describe_tensor`, `matching._l2_search_device`).

Under numba's CUDA simulator (no GPU, the tests) the same device code runs eagerly on the CPU.
Not thread-safe: one FrameGraph serves one thread.
"""

from __future__ import annotations

import numbers

import numpy as np

from .constants import MAX_EDGE_STRETCH, N_KEYPOINTS
from .features import Matches
from .frame import RGBDFrame
from .geodesic.polar import walk_starts
from .gpu import (DeviceFeatures, WalkBuffers, _as_numba, _numba_on, check_gpu_descriptor, features_on,
                  gaussian_blur_torch, mesh_from_depth, require_cuda, valid_descriptors_finite, walk_and_sample)
from .matching import _finish_matches, _l2_search_device, check_match_options


class FrameGraph:
    """GeoPatch features (and matches against a fixed reference) of the frames of one camera, each
    frame one CUDA graph replay.

    Args:
        descriptor: a GeoPatch on a CUDA device with the torch backend
            (`GeoPatch(device="cuda", backend="torch")`).
        like: a frame of the stream: its size and intrinsics are the graph's, and when the
            descriptor's depth_config is "auto" its depth profile is measured on it once (as
            `depth.sequence_depth_profile` does for a sequence).
        n: the most keypoints a frame will have (>= 1); fewer are padded, more are refused.
        reference: optional `Features` or `gpu.DeviceFeatures` (at least one keypoint, float
            descriptors of the same size, e.g. a template frame's GeoPatch features) that `match`
            matches every frame against.
        half: run the CNN under float16 autocast (`gpu.compute_cuda(..., half=True)`).
        graph: False runs the same device code eagerly, without a graph (to compare, or where a
            capture fails); under the simulator it always does.

    Example (a template tracked through a stream):
        graph = FrameGraph(net, template, n=2048, reference=net.compute_cuda(template, kps0))
        for frame in frames:
            features, matches = graph.match(frame, geofeat.detect(frame, 2048))
    """

    def __init__(self, descriptor, like: RGBDFrame, n: int = N_KEYPOINTS, reference=None, half: bool = False,
                 graph: bool = True) -> None:
        import torch

        from .depth import depth_profile, resolve_depth_config

        check_gpu_descriptor(descriptor)
        if not isinstance(like, RGBDFrame):
            raise TypeError(f"like: expected an RGBDFrame, got {type(like).__name__}")
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
            raise ValueError(f"n: expected a whole number of keypoints >= 1, got {n!r}")
        self.descriptor, self.n, self.half = descriptor, int(n), bool(half)
        self.dev = dev = require_cuda(descriptor.device)
        self.shape, self.K = tuple(like.shape), np.array(like.K, np.float64)
        config = descriptor.depth_config
        self.config = resolve_depth_config(depth_profile(like) if config == "auto" else config)
        H, W = self.shape
        cuda = dev.type == "cuda"
        self._pinned = [torch.zeros(shape, dtype=dtype, pin_memory=cuda) for shape, dtype in (
            ((H, W), torch.float32), ((H, W), torch.float32), ((self.n, 2), torch.float64), ((self.n,), torch.bool))]
        self._inputs = [torch.zeros_like(p, device=dev) for p in self._pinned]  # depth, image, starts, mask
        self._K = torch.from_numpy(self.K).to(dev)
        self._copied = torch.cuda.Event() if cuda else None  # the last inputs' copies are done with the pinned ones
        self._reference = None if reference is None else _reference_tensors(reference, dev)
        if self._reference is not None and self._reference[0].shape[1] != descriptor.config.dim:
            raise ValueError(f"reference: {self._reference[0].shape[1]}-d descriptors, but the descriptor gives "
                             f"{descriptor.config.dim}-d ones")
        self.mesh = None
        self._load(like, np.zeros((0, 2)))
        self.mesh = mesh_from_depth(self._inputs[0], self.config, self.K, MAX_EDGE_STRETCH)  # allocates the buffers
        self._walk = WalkBuffers(self.n, descriptor.config.n_rings, descriptor.config.n_angles, dev)
        with _numba_on(dev):  # made once, outside the capture
            self._views = (_as_numba(self._inputs[2]), _as_numba(self._K))  # starts, K
        self._out: dict = {}
        self._graph = None
        if graph and cuda:
            with torch.cuda.device(dev):  # the capture's stream is the current device's: make it `dev`
                self._graph = _capture(self._run, dev)

    def __repr__(self) -> str:
        H, W = self.shape
        kind = "CUDA graph" if self._graph is not None else "eager"
        ref = "" if self._reference is None else f", reference of {len(self._reference[0])} keypoints"
        return f"FrameGraph({W}x{H} frames, up to {self.n} keypoints, {kind} on {self.dev}{ref})"

    def compute(self, frame: RGBDFrame, keypoints) -> DeviceFeatures:
        """`gpu.compute_cuda(descriptor, frame, keypoints)` as one graph replay: DeviceFeatures whose
        descriptors (N, dim) float32 and valid flags (N,) stay on the GPU (copies, not the graph's
        buffers). The frame must have the graph's size and intrinsics, and at most `n` keypoints."""
        kps = self._replay(frame, keypoints)
        count = len(kps)
        desc, valid = self._out["descriptors"], self._out["valid"]
        return DeviceFeatures(kps.xy, desc[:count].clone(), valid[:count].clone(), angles=kps.angles,
                              sizes=kps.sizes, scores=kps.scores)

    def match(self, frame: RGBDFrame, keypoints, mutual: bool = False,
              ratio: float | None = None) -> tuple[DeviceFeatures, Matches]:
        """`compute`, then `gpu.match_cuda(reference, features, mutual, ratio)` inside the same replay:
        (the frame's DeviceFeatures, Matches from the reference's keypoints to the frame's). Only the
        matches come back to the host."""
        if self._reference is None:
            raise ValueError("match: this FrameGraph has no reference (FrameGraph(..., reference=FEATURES))")
        check_match_options(ratio, mutual)
        features = self.compute(frame, keypoints)
        best_d, best_j, second_d, col_j = (t.to("cpu", non_blocking=True) for t in self._out["search"])
        finite = self._out["finite"].to("cpu", non_blocking=True)
        if self._copied is not None:
            import torch

            torch.cuda.current_stream(self.dev).synchronize()
        if not bool(finite):
            raise ValueError("descriptors: the frame's GeoPatch descriptors have NaN or infinite values at valid "
                             "keypoints")
        count = len(features)
        return features, _finish_matches(np.sqrt(best_d.numpy().astype(np.float64)), best_j.numpy(),
                                         np.sqrt(second_d.numpy().astype(np.float64)), col_j.numpy()[:count],
                                         ratio=ratio, mutual=mutual)

    def _replay(self, frame: RGBDFrame, keypoints):
        from .geodesic.mesh import check_frame_arrays
        from .keypoints import as_keypoints

        if not isinstance(frame, RGBDFrame):
            raise TypeError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
        if tuple(frame.shape) != self.shape:
            raise ValueError(f"frame: {frame.shape[1]}x{frame.shape[0]}, but this FrameGraph holds "
                             f"{self.shape[1]}x{self.shape[0]} frames; make a new FrameGraph for it")
        if not np.array_equal(np.asarray(frame.K, np.float64), self.K):
            raise ValueError("frame: its intrinsics K differ from this FrameGraph's; make a new FrameGraph for "
                             "another camera")
        check_frame_arrays(frame)  # as `frame_mesh` checks them for `compute_cuda`: a depth edited in place
        kps = as_keypoints(keypoints, frame.shape)
        if len(kps) > self.n:
            raise ValueError(f"keypoints: {len(kps)}, but this FrameGraph holds at most n={self.n}")
        self._load(frame, kps.xy)
        if self._graph is not None:
            import torch

            with torch.cuda.device(self.dev):  # a replay launches on the current device's stream
                self._graph.replay()
        else:
            self._run()
        return kps

    def _load(self, frame: RGBDFrame, xy: np.ndarray) -> None:
        """Copy the frame's filled depth, gray image, walk starts and keypoint mask into the pinned
        buffers (once the previous frame's copies are done with them), then onto the device."""
        from .depth import filled_depth

        if self._copied is not None:
            self._copied.synchronize()
        depth, image, starts, mask = (p.numpy() for p in self._pinned)
        depth[:] = filled_depth(frame.depth, self.config)
        image[:] = frame.image
        if len(xy):  # (the mesh, which knows its scale, exists from the first frame with keypoints on)
            starts[:len(xy)] = walk_starts(self.mesh, xy)
        starts[len(xy):] = starts[0] if len(xy) else 0.0  # padding: walked (a real start), marked invalid
        mask[:] = np.arange(self.n) < len(xy)
        for device_buffer, host_buffer in zip(self._inputs, self._pinned):
            device_buffer.copy_(host_buffer, non_blocking=True)
        if self._copied is not None:
            import torch

            self._copied.record(torch.cuda.current_stream(self.dev))  # `dev`'s stream, whatever device is current

    def _run(self) -> None:
        """The device work of one frame (what the graph holds): mesh, walk, sampling, CNN, search."""
        depth, image, _, mask = self._inputs
        net = self.descriptor
        mesh_from_depth(depth, self.config, self.K, MAX_EDGE_STRETCH, out=self.mesh)
        values, valid = walk_and_sample(self.mesh.tables, *self._views, gaussian_blur_torch(image, float(net.blur_px)),
                                        net.radius, self._walk, mask=mask)
        desc = net.describe_tensor(values, valid, half=self.half)
        self._out["descriptors"], self._out["valid"] = desc, valid
        if self._reference is not None:
            ref, ref_valid = self._reference
            self._out["search"] = _l2_search_device(ref, desc, ref_valid, valid, True)
            self._out["finite"] = valid_descriptors_finite(desc, valid)


def _reference_tensors(reference, dev) -> tuple:
    """(descriptors (N0, D) float, valid (N0,) bool) of `reference` on `dev` (N0 >= 1), checked as
    `gpu.match_cuda` checks its features (`gpu.features_on`), and copied: the graph's own."""
    import torch

    desc, valid = features_on(reference, "reference", dev)
    if desc.ndim != 2 or not desc.dtype.is_floating_point:
        raise ValueError(f"reference: expected (N, D) float descriptors (GeoPatch), got {desc.dtype} "
                         f"{tuple(desc.shape)}")
    if len(desc) == 0:  # (the search's best row per frame keypoint needs one)
        raise ValueError("reference: no keypoints; a FrameGraph matches against at least one")
    if not bool(valid_descriptors_finite(desc, valid)):
        raise ValueError("reference: NaN or infinite descriptors at valid keypoints; mark them invalid or drop them")
    return desc.clone(memory_format=torch.contiguous_format), valid.clone()  # fixed, as checked


def _capture(run, dev):
    """A torch CUDA graph of `run()`, after three warm-up calls on a side stream (cuDNN's choices,
    numba's compilation and torch's allocator settle before the capture, as torch's docs ask)."""
    import torch

    side = torch.cuda.Stream(dev)
    side.wait_stream(torch.cuda.current_stream(dev))
    with torch.cuda.stream(side):
        for _ in range(3):
            run()
    torch.cuda.current_stream(dev).wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    try:
        with torch.cuda.graph(graph, capture_error_mode="thread_local"):
            run()
    except RuntimeError as error:
        raise RuntimeError(f"FrameGraph: the CUDA graph capture failed ({error}); FrameGraph(..., graph=False) "
                           "runs the same code without a graph") from error
    return graph
