"""A fresh frame of the GPU path as one CUDA graph replay (`geofeat.gpu_graph.FrameGraph`) against the
eager GPU path (`gpu.compute_cuda` + `gpu.match_cuda`), in one process.

Run (on a machine with a CUDA GPU, numba's CUDA target and a CUDA build of torch):
    PYTHONPATH=src python3 benchmarks/bench_frame_graph.py [--repeats 30] [--keypoints 2048]

The shipped Kinect frame's 90-degree roll, SIFT keypoints (detected once, not timed), matched against
the unrolled frame's GeoPatch features; the depth profile measured once (as for a stream). Every
timed call gets a fresh RGBDFrame (no mesh cached on it) and is synchronised before and after;
printed: median and best of `repeats` calls, for the fp32 and the fp16 CNN, then the host's share
(hole filling) and the replay alone. First it checks that both paths give the same matches and
descriptors.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--keypoints", type=int, default=2048)
    a = ap.parse_args()

    import torch

    import geofeat
    from geofeat.depth import depth_profile, filled_depth, resolve_depth_config
    from geofeat.descriptors.geopatch import GeoPatch
    from geofeat.frame import RGBDFrame
    from geofeat.gpu import compute_cuda, match_cuda, require_cuda
    from geofeat.gpu_graph import FrameGraph

    try:
        dev = require_cuda("cuda")
    except RuntimeError as error:  # `make bench` on a machine without a GPU
        print(f"bench_frame_graph: skipped: {error}")
        return
    if dev.type != "cuda":  # numba's CUDA simulator: no graph to time
        print("bench_frame_graph: skipped: numba's CUDA simulator has no CUDA graphs")
        return
    print(f"{torch.cuda.get_device_name(dev)}; torch {torch.__version__}; load average {os.getloadavg()}",
          flush=True)
    f0 = geofeat.read_demo_frame()
    f1 = f0.rotated90(1)
    k0, k1 = (geofeat.detect(f, a.keypoints, detector="sift") for f in (f0, f1))
    profile = depth_profile(f1)
    net = GeoPatch(device="cuda", backend="torch", depth_config=profile)

    def fresh():
        return RGBDFrame(f1.color, f1.depth.copy(), f1.K)

    def sync():
        torch.cuda.synchronize(dev)

    def timed(name, fn):
        frames = [fresh() for _ in range(a.repeats + 3)]  # built beforehand: the caller's I/O
        for f in frames[:3]:
            fn(f)
        walls = []
        for f in frames[3:]:
            sync()
            t = time.perf_counter()
            fn(f)
            sync()
            walls.append(time.perf_counter() - t)
        print(f"{name:<58} median {1e3 * statistics.median(walls):7.3f}   best {1e3 * min(walls):7.3f} ms", flush=True)

    for half in (False, True):
        cnn = "fp16" if half else "fp32"
        reference = compute_cuda(net, f0, k0, half=half)
        graph = FrameGraph(net, f1, n=len(k1), reference=reference, half=half)
        got_features, got = graph.match(fresh(), k1, mutual=True)
        want_features = compute_cuda(net, fresh(), k1, half=half)
        want = match_cuda(reference, want_features, mutual=True)
        diff = float((got_features.descriptors - want_features.descriptors).abs().max())
        print(f"{cnn}: FrameGraph against compute_cuda + match_cuda: mutual matches identical "
              f"{np.array_equal(got.matches0, want.matches0)} ({int((want.matches0 >= 0).sum())} of them), "
              f"descriptors max difference {diff:.2e}", flush=True)
        timed(f"eager: compute_cuda + match_cuda, CNN {cnn}",
              lambda f: match_cuda(reference, compute_cuda(net, f, k1, half=half), mutual=True))
        timed(f"FrameGraph.match, CNN {cnn}", lambda f: graph.match(f, k1, mutual=True))
    cfg = resolve_depth_config(profile)
    timed("  host: filled_depth", lambda f: filled_depth(f.depth, cfg))
    timed("  graph.replay alone (fp16)", lambda f: graph._graph.replay())
    print(f"load average {os.getloadavg()}", flush=True)


if __name__ == "__main__":
    main()
