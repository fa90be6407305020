"""Issue 21's GPU path (`device="cuda"`), per stage, against the CPU path in the same process.

Run (on a machine with a CUDA GPU, numba's CUDA target and a CUDA build of torch):
    PYTHONPATH=src python3 benchmarks/bench_gpu.py [--keypoints 2048] [--repeats 20] [--json out.json]

The pair is the shipped Kinect frame and its 90-degree roll, 2048 SIFT keypoints each (detection is
not timed: both paths get the same keypoints). Per frame:
- walk: the geodesic walk alone (GPU: `walk_cuda.walk_polar_cuda` on device inputs; CPU: `walk_polar`);
- f(.) with the mesh reused: walk + blur + patch sampling (`gpu.polar_patches_cuda` /
  `geofeat.polar_patches(..., mesh=mesh)`);
- depth + mesh + walk tables of a fresh frame: on the GPU (`gpu.build_mesh_cuda`: hole filling on
  the host, the smoothing pyramid, back-projection and one thread per face on the GPU) and on the
  host (`geodesic.mesh.build_mesh` + `walk_tables`); hole filling alone (host, `depth.fill_holes`);
- f(.) on a fresh frame: the above, then the walk, blur and sampling (GPU) / `polar_patches` on a
  new RGBDFrame (CPU). The depth profile is resolved once for the stream (as `geofeat bench` does
  per sequence); one row also shows the GPU path with depth_config="auto", which measures every
  frame's depth noise on the host;
- CNN: GeoPatch on 2048 patches (GPU: torch fp32, TF32 off; CPU: the default onnx-int8 backend and torch);
- match: GeoPatch L2 2048 x 2048 and GeoBit Hamming 2048 x 2048 x 16 rotations (GPU: matrix products,
  descriptors already on the device; CPU: `geofeat.match`);
- total per frame: f(.) + CNN + one L2 match against the previous frame's features (the streaming
  case: every new frame is described and matched once), mesh reused and fresh (fp32 and fp16 CNN).
GPU times are wall times with torch.cuda.synchronize() before and after each call, after warm-up;
the median and the best of `repeats` calls are printed. The same run checks that the GPU results
equal the CPU ones (walk coordinates, patch values, descriptors, matches).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from common import wall_times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keypoints", type=int, default=2048)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--cpu-repeats", type=int, default=5)
    ap.add_argument("--json", default=None, help="also write the figures here")
    a = ap.parse_args()

    import numba
    import torch

    import geofeat
    from geofeat.descriptors.geobit import GeoBit
    from geofeat.descriptors.geopatch import GeoPatch
    from geofeat.frame import RGBDFrame
    from geofeat.depth import depth_profile, fill_holes
    from geofeat.geodesic.mesh import build_mesh, frame_mesh
    from geofeat.geodesic.walk import MAX_CROSSINGS, walk_polar
    from geofeat.gpu import (_as_numba, _MESH_ATTR, build_mesh_cuda, compute_cuda, device_mesh_tables, match_cuda,
                             polar_patches_cuda, require_cuda, simulated)
    from geofeat.geodesic.walk_cuda import walk_polar_cuda
    from geofeat.keypoints import detect
    from geofeat.matching import match

    try:
        dev = require_cuda("cuda")  # under NUMBA_ENABLE_CUDASIM=1 (a smoke test of this script): the CPU
    except RuntimeError as error:  # `make bench` on a machine without a GPU
        print(f"bench_gpu: skipped: {error}")
        return
    sim = simulated()
    name = "CUDA simulator (CPU)" if sim else torch.cuda.get_device_name(dev)
    print(f"device: {name}; torch {torch.__version__} (CUDA {torch.version.cuda}); "
          f"numba {numba.__version__}; CPU: {os.cpu_count()} cores, numba threads {numba.get_num_threads()}, "
          f"torch threads {torch.get_num_threads()}; load average {os.getloadavg()[0]:.2f}", flush=True)
    n = a.keypoints
    frames = [geofeat.read_demo_frame()]
    frames.append(frames[0].rotated90(1))
    kps = [detect(f, n, detector="sift") for f in frames]
    meshes = [frame_mesh(f) for f in frames]
    profile = depth_profile(frames[0])  # once per stream
    gp_gpu = GeoPatch(device="cpu" if sim else "cuda", backend="torch")
    gp_stream = GeoPatch(device="cpu" if sim else "cuda", backend="torch", depth_config=profile)
    gp_cpu_stream = GeoPatch(device="cpu", depth_config=profile)
    gp_cpu = GeoPatch(device="cpu")  # the CPU default backend (onnx-int8)
    gp_cpu_torch = GeoPatch(device="cpu", backend="torch")
    gb = GeoBit()
    print(f"keypoints: {[len(k) for k in kps]}; CPU GeoPatch backend {gp_cpu.backend}", flush=True)

    def sync():
        if not sim:
            torch.cuda.synchronize(dev)

    def t_gpu(fn, repeats=a.repeats, warm=3):
        for _ in range(warm):
            fn()
        sync()
        ts = []
        for _ in range(repeats):
            sync()
            t = time.perf_counter()
            fn()
            sync()
            ts.append(time.perf_counter() - t)
        return statistics.median(ts) * 1e3, min(ts) * 1e3

    def t_cpu(fn, repeats=a.cpu_repeats, warm=1):
        ts = wall_times(fn, repeats, warm)
        return statistics.median(ts) * 1e3, min(ts) * 1e3

    def fresh(frame):
        return RGBDFrame(frame.color if frame.color is not None else frame.image, frame.depth.copy(), frame.K)

    def fresh_frames(gpu: bool = True):
        """A callable giving a new RGBDFrame (nothing cached on it) per timed call, built beforehand:
        reading and checking a frame is the caller's I/O, not f(.) (its own row below)."""
        it = iter([fresh(frames[1]) for _ in range(3 + a.repeats if gpu else 1 + a.cpu_repeats)])
        return lambda: next(it)

    rows: list[tuple[str, str, tuple[float, float]]] = []

    def report(stage, where, times):
        rows.append((stage, where, times))
        print(f"  {stage:<44} {where:<22} median {times[0]:9.3f} ms   best {times[1]:9.3f} ms", flush=True)

    # ---- correctness: GPU against CPU, both frames -------------------------------------------
    print("\nGPU against CPU:", flush=True)
    checks = {}
    feats_g, feats_c, bits_g, bits_c = [], [], [], []
    for i, (f, k, m) in enumerate(zip(frames, kps, meshes)):
        pc = geofeat.polar_patches(f, k, mesh=m)
        pg = polar_patches_cuda(f, k, mesh=m).to_host()
        v = pc.valid
        dc = np.abs(pg.coords[v].astype(np.float64) - pc.coords[v])
        close = (dc < 1e-5).all(-1)
        fg = compute_cuda(gp_gpu, f, k, mesh=m)
        fc = gp_cpu_torch.compute(f, k, patches=pc)
        checks[f"frame{i}"] = dict(
            valid_equal=bool(np.array_equal(pg.valid, v)),
            reached_equal=bool(np.array_equal(pg.rings_reached, pc.rings_reached)),
            coords_max_px=float(np.nanmax(dc)), samples_over_1e5px=float(1 - close.mean()),
            values_max=float(np.abs(pg.values - pc.values)[v].max()),
            values_max_where_coords_agree=float(np.abs(pg.values[v][close] - pc.values[v][close]).max()),
            descriptor_max=float(np.abs(fg.descriptors.cpu().numpy() - fc.descriptors).max()),
        )
        print(f"  frame {i}: {checks[f'frame{i}']}", flush=True)
        feats_g.append(fg)
        feats_c.append(fc)
        gbc = gb.compute(f, k, patches=pc)
        bits_c.append(gbc)
        bits_g.append(type(fg)(gbc.keypoints, torch.from_numpy(gbc.descriptors).to(dev),
                               torch.from_numpy(gbc.valid).to(dev)))
    mc = match(feats_c[0], feats_c[1], mutual=True)
    mg = match_cuda(feats_g[0], feats_g[1], mutual=True)
    same_desc = match(feats_g[0].to_host(), feats_g[1].to_host(), mutual=True)
    checks["l2_matches_agree_gpu_path_vs_cpu_path"] = float((mg.matches0 == mc.matches0).mean())
    checks["l2_matches_identical_same_descriptors"] = bool(np.array_equal(mg.matches0, same_desc.matches0))
    hc = match(bits_c[0], bits_c[1], mutual=True)
    hg = match_cuda(bits_g[0], bits_g[1], mutual=True)
    checks["geobit_matches_identical"] = bool(np.array_equal(hg.matches0, hc.matches0))
    checks["geopatch_mutual_matches"] = int((mc.matches0 >= 0).sum())
    print(f"  matches: { {k: v for k, v in checks.items() if not k.startswith('frame')} }", flush=True)

    # ---- timings ---------------------------------------------------------------------------
    print(f"\nPer frame, {n} keypoints (GPU: median / best of {a.repeats}; CPU: of {a.cpu_repeats}):", flush=True)
    f0, k0, m0 = frames[1], kps[1], meshes[1]
    local, edges = m0.walk_tables
    starts = m0.image_to_mesh(k0.xy) + np.array([1.3e-6, 0.7e-6])
    dt = device_mesh_tables(m0, dev)
    starts_d = _as_numba(torch.from_numpy(starts).to(dev))
    K_d = _as_numba(torch.from_numpy(np.ascontiguousarray(f0.K, np.float64)).to(dev))
    report("walk", "GPU", t_gpu(lambda: walk_polar_cuda(*dt, starts_d, K_d, 0.075, 32, 32, MAX_CROSSINGS)))
    report("walk", "CPU", t_cpu(lambda: walk_polar(m0.points, m0.face_ok, m0.normals, local, edges, starts, f0.K,
                                                   0.075, 32, 32, MAX_CROSSINGS)))

    def upload_tables():
        m0.__dict__.pop(_MESH_ATTR, None)
        device_mesh_tables(m0, dev)

    report("mesh tables upload (once per mesh)", "host->GPU", t_gpu(upload_tables))
    report("f(.) mesh reused: walk + blur + sampling", "GPU", t_gpu(lambda: polar_patches_cuda(f0, k0, mesh=m0)))
    report("f(.) mesh reused: walk + blur + sampling", "CPU", t_cpu(lambda: geofeat.polar_patches(f0, k0, mesh=m0)))
    # the GPU-built mesh against the host's, on the timed frame
    mh, mg = build_mesh(f0, profile), build_mesh_cuda(f0, profile, device=dev).to_host()
    checks["device_mesh"] = dict(
        face_ok_equal=bool(np.array_equal(mh.face_ok, mg.face_ok)),
        points_max_m=float(np.nanmax(np.abs(mh.points - mg.points))),
        normals_max=float(np.abs(mh.normals - mg.normals).max()),
        local_max_m=float(np.abs(mh.walk_tables[0] - mg.walk_tables[0]).max()))
    print(f"  GPU-built mesh against the host's ({profile} profile): {checks['device_mesh']}", flush=True)
    report("hole filling (host, part of the next row)", "CPU", t_cpu(lambda: fill_holes(f0.depth)))
    report("frame construction (RGBDFrame: gray image, checks)", "CPU", t_cpu(lambda: fresh(f0)))
    nxt = fresh_frames()
    report("depth + mesh + walk tables, fresh frame", "host fill + GPU",
           t_gpu(lambda: build_mesh_cuda(nxt(), profile, device=dev)))
    nxt = fresh_frames(gpu=False)
    report("depth + mesh + walk tables, fresh frame", "CPU",
           t_cpu(lambda: build_mesh(nxt(), profile).walk_tables))
    nxt = fresh_frames()
    report("f(.) fresh frame", "GPU (fill on host)",
           t_gpu(lambda: polar_patches_cuda(nxt(), k0, depth_config=profile)))

    def host_mesh_path(frame):  # the previous release's GPU path: mesh on the host, then uploaded
        return polar_patches_cuda(frame, k0, mesh=frame_mesh(frame, profile))

    nxt = fresh_frames()
    report("f(.) fresh frame, host mesh uploaded", "host + GPU (before)", t_gpu(lambda: host_mesh_path(nxt())))
    nxt = fresh_frames()
    report("f(.) fresh frame, depth_config='auto'", "GPU (+ host noise check)",
           t_gpu(lambda: polar_patches_cuda(nxt(), k0)))
    nxt = fresh_frames(gpu=False)
    report("f(.) fresh frame", "CPU", t_cpu(lambda: geofeat.polar_patches(nxt(), k0, depth_config=profile)))
    pg = polar_patches_cuda(f0, k0, mesh=m0)
    report("GeoPatch CNN", "GPU torch fp32", t_gpu(lambda: gp_gpu.describe_tensor(pg.values, pg.valid)))
    ref32 = gp_gpu.describe_tensor(pg.values, pg.valid)
    if not sim:
        report("GeoPatch CNN", "GPU torch fp16 autocast",
               t_gpu(lambda: gp_gpu.describe_tensor(pg.values, pg.valid, half=True)))
        d16 = gp_gpu.describe_tensor(pg.values, pg.valid, half=True)
        checks["fp16_descriptor_max_diff"] = float((d16 - ref32).abs().max())
        f16 = type(feats_g[1])(feats_g[1].keypoints, d16, pg.valid)
        checks["fp16_l2_matches_agree"] = float(
            (match_cuda(feats_g[0], f16, mutual=True).matches0
             == match_cuda(feats_g[0], type(f16)(f16.keypoints, ref32, pg.valid), mutual=True).matches0).mean())
        print(f"  fp16 CNN against fp32: {checks['fp16_descriptor_max_diff']:.2e} max descriptor difference, "
              f"{checks['fp16_l2_matches_agree']:.4f} of the mutual L2 matches unchanged", flush=True)
    ph = pg.to_host()
    report("GeoPatch CNN", f"CPU {gp_cpu.backend}", t_cpu(lambda: gp_cpu.describe(ph.values, ph.valid)))
    report("GeoPatch CNN", "CPU torch", t_cpu(lambda: gp_cpu_torch.describe(ph.values, ph.valid)))
    report("match GeoPatch L2 (pair)", "GPU", t_gpu(lambda: match_cuda(feats_g[0], feats_g[1])))
    report("match GeoPatch L2 (pair)", "CPU", t_cpu(lambda: match(feats_c[0], feats_c[1])))
    report("match GeoBit Hamming x16 rot (pair)", "GPU", t_gpu(lambda: match_cuda(bits_g[0], bits_g[1])))
    report("match GeoBit Hamming x16 rot (pair)", "CPU", t_cpu(lambda: match(bits_c[0], bits_c[1])))
    prev_g, prev_c = feats_g[0], feats_c[0]
    report("total: f(.) + CNN + match, mesh reused", "GPU",
           t_gpu(lambda: match_cuda(prev_g, compute_cuda(gp_gpu, f0, k0, mesh=m0))))
    if not sim:
        report("total: f(.) + CNN + match, mesh reused", "GPU, CNN fp16",
               t_gpu(lambda: match_cuda(prev_g, compute_cuda(gp_gpu, f0, k0, mesh=m0, half=True))))
    report("total: f(.) + CNN + match, mesh reused", "CPU",
           t_cpu(lambda: match(prev_c, gp_cpu.compute(f0, k0, mesh=m0))))
    nxt = fresh_frames()
    report("total: f(.) + CNN + match, fresh frame", "GPU (fill on host)",
           t_gpu(lambda: match_cuda(prev_g, compute_cuda(gp_stream, nxt(), k0))))
    if not sim:
        nxt = fresh_frames()
        report("total: f(.) + CNN + match, fresh frame", "GPU, CNN fp16",
               t_gpu(lambda: match_cuda(prev_g, compute_cuda(gp_stream, nxt(), k0, half=True))))
    nxt = fresh_frames(gpu=False)
    report("total: f(.) + CNN + match, fresh frame", "CPU",
           t_cpu(lambda: match(prev_c, gp_cpu_stream.compute(nxt(), k0))))
    print(f"load average after: {os.getloadavg()[0]:.2f}", flush=True)
    if a.json:
        with open(a.json, "w") as fd:
            json.dump({"device": name, "keypoints": n, "checks": checks,
                       "rows": [[s, w, t[0], t[1]] for s, w, t in rows]}, fd, indent=1)


if __name__ == "__main__":
    main()
