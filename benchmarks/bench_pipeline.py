"""The whole geofeat pipeline on a pair, per stage, against OpenCV SIFT in the same process.

Run: PYTHONPATH=src .venv/bin/python benchmarks/bench_pipeline.py [--repeats 5] [--rounds 3]
     [--detector sift|geokey] [--backends torch,onnx,onnx-int8,openvino-int8,openvino-bf16] [--keypoints 2048]

The pair is the shipped Kinect frame and its 90-degree roll, 2048 keypoints each. Stages:
- detect (`geofeat.detect`, per frame);
- f(.) on a fresh frame (a new RGBDFrame: depth preprocessing + mesh + walk) and with the mesh
  reused (`polar_patches(..., mesh=...)`), per frame;
- the GeoPatch CNN per backend (torch, ONNX Runtime fp32, ONNX Runtime int8), per frame;
- GeoPatch match (L2, 2048 x 2048) and GeoBit match (2048 x 2048 x 16 rotations);
- the whole pipeline for the pair (two fresh frames: detect + f(.) + CNN, then the GeoPatch
  match), per CNN backend, timed end to end; and the same through the public one-call API
  (`geofeat.extract` on each fresh frame, which builds the mesh while detecting, with its default
  backend; then `match`);
against OpenCV SIFT detect + compute, compute alone, and detectAndCompute x 2 + BFMatcher L2.

Each stage is timed `repeats` times in each of `rounds` interleaved rounds; the best wall time and
the best process CPU time (user + system of this process, all its threads) are printed, with the
1-minute load average when the stage was timed and the cores' worth of CPU that other processes used
meanwhile (from /proc/stat, less this process's own CPU time; the load average counts this
benchmark's threads too). A ratio is flagged when the load average exceeds 1.5 or other processes
used more than 0.25 cores: they then share the cores, and the ratio to a short OpenCV call is not
the ratio a user sees on an idle machine.
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

import geofeat
from geofeat.descriptors.geobit import GeoBit
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.features import Features
from geofeat.frame import RGBDFrame
from geofeat.geodesic.mesh import build_mesh
from geofeat.keypoints import detect, to_uint8
from geofeat.matching import match

from common import busy_cpu_seconds, others_cores

LOAD_LIMIT = 1.5
#: Other processes' CPU (cores) during a stage above which its ratios are flagged too.
OTHERS_LIMIT = 0.25


def timed(fn, repeats: int) -> tuple[float, float, float, float]:
    """(best wall s, best process CPU s, 1-min load average, other processes' cores) of `repeats` calls
    of fn(). The last is the CPU that the rest of the machine used while the calls ran, in cores
    (`common.others_cores`): unlike the load average, it leaves out this benchmark's own threads."""
    wall, cpu = [], []
    busy0, c0, t0 = busy_cpu_seconds(), time.process_time(), time.perf_counter()
    for _ in range(repeats):
        c, t = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    others = others_cores(busy0, busy_cpu_seconds(), time.process_time() - c0, time.perf_counter() - t0)
    return min(wall), min(cpu), os.getloadavg()[0], others


def fresh(frame: RGBDFrame) -> RGBDFrame:
    """A new RGBDFrame of the same data (no cached mesh)."""
    return RGBDFrame(frame.color if frame.color is not None else frame.image, frame.depth.copy(), frame.K)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--keypoints", type=int, default=2048)
    ap.add_argument("--detector", default="sift", help="geofeat.detect detector (default sift)")
    ap.add_argument("--backends", default="torch:1,torch:2,onnx:1,onnx:2,onnx-int8:1,onnx-int8:2,openvino-int8:1,openvino-int8:2,openvino-bf16:1,openvino-bf16:2",
                    help="GeoPatch backends to time, each BACKEND or BACKEND:THREADS (torch threads or ORT "
                         "intra-op threads; without: the backend's default)")
    a = ap.parse_args()
    n = a.keypoints
    frames = [geofeat.read_demo_frame()]
    frames.append(frames[0].rotated90(1))
    backends = [b.strip() for b in a.backends.split(",") if b.strip()]
    nets = {}
    for spec in backends:
        name, _, th = spec.partition(":")
        nets[spec] = GeoPatch(device="cpu", backend=name, threads=int(th) if th else None)
    gb = GeoBit()
    sift = cv2.SIFT_create(nfeatures=n)
    grays = [to_uint8(f.image) for f in frames]
    bf = cv2.BFMatcher(cv2.NORM_L2)
    kps = [detect(f, n, detector=a.detector) for f in frames]
    meshes = [build_mesh(f) for f in frames]
    patches = [geofeat.polar_patches(f, k, mesh=m) for f, k, m in zip(frames, kps, meshes)]
    cv_kps = [k.to_cv() for k in kps]
    desc = {b: [net.describe(p.values, p.valid) for p in patches] for b, net in nets.items()}
    feats = [Features(p.keypoints, d, p.valid) for p, d in zip(patches, desc[backends[0]])]
    bits = [gb.compute(f, p.keypoints, patches=p) for f, p in zip(frames, patches)]
    threads = {b: (net.session.threads if net.session is not None else net.threads) for b, net in nets.items()}
    print(f"{os.cpu_count()} logical cores; OpenCV {cv2.__version__} threads {cv2.getNumThreads()}; CNN threads "
          f"{threads}; {n} keypoints ({a.detector}); "
          f"valid patches {[int(p.valid.sum()) for p in patches]}; load average {os.getloadavg()}")

    def pipeline(net):
        out = []
        for f in frames:
            f = fresh(f)
            k = detect(f, n, detector=a.detector)
            p = geofeat.polar_patches(f, k)
            out.append(Features(p.keypoints, net.describe(p.values, p.valid), p.valid))
        return match(out[0], out[1])

    def sift_pair():
        res = [sift.detectAndCompute(g, None) for g in grays]
        return bf.match(res[0][1], res[1][1])

    stages = {
        "detect (geofeat, 1 frame)": lambda: detect(frames[0], n, detector=a.detector),
        "f(.) fresh frame (1 frame)": lambda: geofeat.polar_patches(fresh(frames[0]), kps[0]),
        "f(.) mesh reused (1 frame)": lambda: geofeat.polar_patches(frames[0], kps[0], mesh=meshes[0]),
        **{f"CNN {b} (1 frame)": (lambda net=net: net.describe(patches[0].values, patches[0].valid))
           for b, net in nets.items()},
        "GeoPatch match L2 (pair)": lambda: match(feats[0], feats[1]),
        "GeoBit match 16 rot. (pair)": lambda: match(bits[0], bits[1]),
        **{f"pipeline {b} (pair)": (lambda net=net: pipeline(net)) for b, net in nets.items()},
        "geofeat.extract x2 + match (pair)": lambda: match(*[geofeat.extract(fresh(f), n, detector=a.detector)
                                                             for f in frames]),
        "SIFT detect+compute (1 frame)": lambda: sift.detectAndCompute(grays[0], None),
        "SIFT compute (1 frame)": lambda: sift.compute(grays[0], cv_kps[0]),
        "SIFT detectAndCompute x2 + BF L2 (pair)": sift_pair,
    }
    for fn in stages.values():  # warm-up (numba compilation, ORT first-run allocations)
        fn()
    best = {name: [np.inf, np.inf, 0.0, 0.0] for name in stages}
    for _ in range(a.rounds):  # interleaved, so that background load falls on every stage alike
        for name, fn in stages.items():
            w, c, load, others = timed(fn, a.repeats)
            if w < best[name][0]:
                best[name][0], best[name][2], best[name][3] = w, load, others
            best[name][1] = min(best[name][1], c)
    print(f"\n{'stage':42s} {'wall ms':>9s} {'CPU ms':>9s} {'load':>6s} {'others':>7s}")
    for name, (w, c, load, others) in best.items():
        print(f"{name:42s} {1e3 * w:9.1f} {1e3 * c:9.1f} {load:6.2f} {others:7.2f}")
    print("(load: the 1-minute load average, this benchmark's own threads included; others: the cores that "
          "other processes used while the stage's best round ran)")

    def ratio(ours: str, ref: str, goal: str) -> None:
        (w0, c0, l0, o0), (w1, c1, l1, o1) = best[ours], best[ref]
        flags = []
        if max(l0, l1) > LOAD_LIMIT:
            flags.append(f"load average {max(l0, l1):.2f} > {LOAD_LIMIT}")
        if max(o0, o1) > OTHERS_LIMIT:  # NaN (no /proc/stat) compares False: no flag from it
            flags.append(f"other processes used {max(o0, o1):.2f} cores > {OTHERS_LIMIT}")
        flag = f"   [FLAG: {'; '.join(flags)}: not a final figure]" if flags else ""
        print(f"{ours:32s} / {ref:40s} wall {w0 / w1:5.2f}  CPU {c0 / c1:5.2f}  (goal {goal}){flag}")

    print("\nratios (wall from best wall times, CPU from best process CPU times):")
    for b in backends:
        ratio(f"pipeline {b} (pair)", "SIFT detectAndCompute x2 + BF L2 (pair)", "<= 1.5")
    ratio("geofeat.extract x2 + match (pair)", "SIFT detectAndCompute x2 + BF L2 (pair)", "<= 1.5")
    ratio("f(.) mesh reused (1 frame)", "SIFT detect+compute (1 frame)", "<= 0.5")
    ratio("f(.) fresh frame (1 frame)", "SIFT detect+compute (1 frame)", "<= 1.0")
    for b in backends:
        ratio(f"CNN {b} (1 frame)", "SIFT compute (1 frame)", "<= 1")
    torch_specs = [b for b in backends if b.startswith("torch")]
    if torch_specs:  # against torch at its best thread count in this run
        ref = min(torch_specs, key=lambda b: best[f"CNN {b} (1 frame)"][0])
        for b in backends:
            if not b.startswith("torch"):
                ratio(f"CNN {ref} (1 frame)", f"CNN {b} (1 frame)", "speed-up of the CNN")
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
