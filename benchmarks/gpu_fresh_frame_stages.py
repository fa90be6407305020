"""The GPU path's fresh frame, stage by stage: where a frame's time goes on the host and on the GPU.

Run (on a machine with a CUDA GPU, numba's CUDA target and a CUDA build of torch):
    PYTHONPATH=src python3 benchmarks/gpu_fresh_frame_stages.py [--repeats 30] [--no-profile]

The shipped Kinect frame's 90-degree roll, 2048 SIFT keypoints (not timed), the depth profile
resolved once (as for a stream). Each stage is called `repeats` times after 3 warm-up calls, with
torch.cuda.synchronize() before and after each; printed: the median and best of those wall times,
and the median time until the call returned to Python ("host-return": when it equals the wall
time, the stage is bound by its host work, launches included, not by the GPU). Then a cProfile of
30 fresh frames (compute_cuda with the fp16 CNN + match_cuda) by cumulative and by own time.

To compare two versions on one machine, run this script under each version's src/ alternately
(the host's speed drifts between runs by as much as the changes measured)."""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import statistics
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--no-profile", action="store_true", help="skip the cProfile")
    a = ap.parse_args()

    import torch

    import geofeat
    from geofeat.depth import depth_profile, filled_depth, resolve_depth_config, scale_intrinsics
    from geofeat.descriptors.geopatch import GeoPatch
    from geofeat.frame import RGBDFrame
    from geofeat.geodesic.mesh import frame_fingerprint
    from geofeat.gpu import (backproject_torch, build_mesh_cuda, compute_cuda, gaussian_blur_torch, match_cuda,
                             polar_patches_cuda, require_cuda, sample_bilinear_torch, smooth_depth_torch)
    from geofeat.keypoints import detect

    dev = require_cuda("cuda")
    print(f"{torch.cuda.get_device_name(dev)}; load average {os.getloadavg()}", flush=True)
    f0 = geofeat.read_demo_frame()
    f1 = f0.rotated90(1)
    k0, k1 = detect(f0, 2048, detector="sift"), detect(f1, 2048, detector="sift")
    profile = depth_profile(f0)
    cfg = resolve_depth_config(profile)
    net = GeoPatch(device="cuda", backend="torch", depth_config=profile)

    def fresh(f):
        return RGBDFrame(f.color, f.depth.copy(), f.K)

    def sync():
        torch.cuda.synchronize(dev)

    def timed(name, fn):
        for _ in range(3):
            fn()
        sync()
        walls, returns = [], []
        for _ in range(a.repeats):
            sync()
            t = time.perf_counter()
            fn()
            h = time.perf_counter()
            sync()
            walls.append(time.perf_counter() - t)
            returns.append(h - t)
        print(f"{name:<40} sync median {1e3 * statistics.median(walls):7.3f} best {1e3 * min(walls):7.3f}   "
              f"host-return median {1e3 * statistics.median(returns):7.3f} ms", flush=True)

    frames = iter([fresh(f1) for _ in range(4 * (a.repeats + 3) + 35)])  # built beforehand: the caller's I/O
    timed("RGBDFrame(...) construction", lambda: fresh(f1))
    timed("frame_fingerprint", lambda: frame_fingerprint(f1))
    timed("filled_depth (host)", lambda: filled_depth(f1.depth, cfg))
    filled = filled_depth(f1.depth, cfg)
    timed("upload depth", lambda: torch.from_numpy(filled).to(dev))
    depth_t = torch.from_numpy(filled).to(dev)
    timed("smooth_depth_torch", lambda: smooth_depth_torch(depth_t, cfg.smooth_levels, cfg.mesh_scale))
    smoothed = smooth_depth_torch(depth_t, cfg.smooth_levels, cfg.mesh_scale)
    K_mesh = scale_intrinsics(f1.K, smoothed.shape[1] / f1.shape[1], smoothed.shape[0] / f1.shape[0])
    timed("backproject_torch", lambda: backproject_torch(smoothed, K_mesh))
    timed("build_mesh_cuda (fresh frame)", lambda: build_mesh_cuda(next(frames), profile, device=dev))
    mesh = build_mesh_cuda(f1, profile, device=dev)
    timed("polar_patches_cuda (mesh given)", lambda: polar_patches_cuda(f1, k1, mesh=mesh, depth_config=profile))
    image = torch.from_numpy(np.ascontiguousarray(f1.image, np.float32)).to(dev)
    timed("upload image", lambda: torch.from_numpy(np.ascontiguousarray(f1.image, np.float32)).to(dev))
    timed("gaussian_blur_torch", lambda: gaussian_blur_torch(image, 1.0))
    patches = polar_patches_cuda(f1, k1, mesh=mesh, depth_config=profile)
    timed("sample_bilinear_torch", lambda: sample_bilinear_torch(image, patches.coords))
    timed("describe_tensor fp32", lambda: net.describe_tensor(patches.values, patches.valid))
    timed("describe_tensor fp16", lambda: net.describe_tensor(patches.values, patches.valid, half=True))
    previous = compute_cuda(net, f0, k0)
    current = compute_cuda(net, f1, k1)
    timed("match_cuda L2", lambda: match_cuda(previous, current))
    timed("compute_cuda fresh fp32", lambda: compute_cuda(net, next(frames), k1))
    timed("TOTAL fresh fp32 (compute+match)", lambda: match_cuda(previous, compute_cuda(net, next(frames), k1)))
    timed("TOTAL fresh fp16 (compute+match)",
          lambda: match_cuda(previous, compute_cuda(net, next(frames), k1, half=True)))
    if a.no_profile:
        return
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(30):
        match_cuda(previous, compute_cuda(net, next(frames), k1, half=True))
    sync()
    prof.disable()
    stats = pstats.Stats(prof)
    stats.sort_stats("cumtime").print_stats(45)
    stats.sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
