"""The walk's keypoint order: `walk_polar` (keypoints walked in bands of mesh rows, `walk_order`)
against the same kernel walking them in the order given (`walk_polar_in_order` with 0..N-1, as
every release before this one did), interleaved in one process, on the shipped Kinect frame.

Prints the best and median wall time of each, their ratio, the load average and the cores other
processes used, for SIFT's and GeoKey's 2048 keypoints, with 2 numba threads and with 1; checks
first that both orders give identical samples, coordinates and rings reached. With `--pair`, also
the whole `geofeat.extract` x 2 + `match` pair (GeoKey, fresh frames, the Kinect frame and its 90
degree roll) with each order, and the time its two walks took.
Run: PYTHONPATH=src .venv/bin/python benchmarks/bench_walk_order.py [--rounds 9] [--pair]
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np

from common import busy_cpu_seconds, others_cores

import geofeat
import geofeat.geodesic.polar as polar
from geofeat.constants import DEFAULT_RADIUS_M, N_ANGLES, N_RINGS
from geofeat.geodesic.mesh import build_mesh
from geofeat.geodesic.polar import walk_starts
from geofeat.geodesic.walk import MAX_CROSSINGS, walk_polar, walk_polar_in_order
from geofeat.frame import RGBDFrame
from geofeat.keypoints import detect


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--keypoints", type=int, default=2048)
    ap.add_argument("--pair", action="store_true", help="also the whole extract pair with each order")
    a = ap.parse_args()
    frame = geofeat.read_demo_frame()
    mesh = build_mesh(frame)
    local, edges = mesh.walk_tables
    print(f"{os.cpu_count()} logical cores; Kinect frame, mesh {mesh.points.shape[1]} x {mesh.points.shape[0]}; "
          f"{N_ANGLES} x {N_RINGS} samples, radius {DEFAULT_RADIUS_M} m; load average {os.getloadavg()}")
    print(f"{'keypoints':10s} {'threads':>7s} {'given order ms':>16s} {'walk_order ms':>15s} {'ratio':>6s} "
          f"{'load':>5s} {'others':>6s}   (best / median of {a.rounds})")
    for detector in ("sift", "geokey"):
        starts = walk_starts(mesh, detect(frame, a.keypoints, detector=detector).xy)
        args = (mesh.points, mesh.face_ok, mesh.normals, local, edges, starts, frame.K, DEFAULT_RADIUS_M, N_ANGLES,
                N_RINGS, MAX_CROSSINGS)
        given = np.arange(len(starts))
        runs = {"given": lambda: walk_polar_in_order(*args, given), "sorted": lambda: walk_polar(*args)}
        same = all(np.array_equal(x, y, equal_nan=True) for x, y in zip(runs["given"](), runs["sorted"]()))
        if not same:
            raise SystemExit("the two orders gave different results")
        for threads in (2, 1):
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            times = {name: [] for name in runs}
            busy0, c0, t0 = busy_cpu_seconds(), time.process_time(), time.perf_counter()
            for _ in range(a.rounds):
                for name, fn in runs.items():
                    t = time.perf_counter()
                    fn()
                    times[name].append(1e3 * (time.perf_counter() - t))
            others = others_cores(busy0, busy_cpu_seconds(), time.process_time() - c0, time.perf_counter() - t0)
            g, s = times["given"], times["sorted"]
            print(f"{detector:10s} {numba.get_num_threads():7d} {min(g):7.1f} / {np.median(g):6.1f} "
                  f"{min(s):6.1f} / {np.median(s):6.1f} {min(s) / min(g):6.2f} {os.getloadavg()[0]:5.2f} {others:6.2f}")
    print("identical samples, coordinates and rings reached in both orders")
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # the loop above ends on 1 thread
    if a.pair:
        extract_pair(frame, a.keypoints, a.rounds)


def extract_pair(frame, n: int, rounds: int) -> None:
    """`geofeat.extract` on two fresh frames + `match`, with `polar_patches`' walk in each order."""
    frames = [frame, frame.rotated90(1)]
    walk_ms: list[float] = []

    def timed(walk):
        def run(*args):
            t = time.perf_counter()
            out = walk(*args)
            walk_ms.append(1e3 * (time.perf_counter() - t))
            return out
        return run

    orders = {"given": timed(lambda *args: walk_polar_in_order(*args, np.arange(len(args[5])))),
              "walk_order": timed(walk_polar)}
    times = {name: ([], []) for name in orders}

    def pair():
        fresh = [RGBDFrame(f.color if f.color is not None else f.image, f.depth.copy(), f.K) for f in frames]
        return geofeat.match(*[geofeat.extract(f, n, detector="geokey") for f in fresh])

    shipped = polar.walk_polar
    try:
        for walk in orders.values():  # warm-up
            polar.walk_polar = walk
            pair()
        busy0, c0, t0 = busy_cpu_seconds(), time.process_time(), time.perf_counter()
        for _ in range(rounds):
            for name, walk in orders.items():
                polar.walk_polar = walk
                walk_ms.clear()
                t = time.perf_counter()
                pair()
                times[name][0].append(1e3 * (time.perf_counter() - t))
                times[name][1].append(sum(walk_ms))
        others = others_cores(busy0, busy_cpu_seconds(), time.process_time() - c0, time.perf_counter() - t0)
    finally:
        polar.walk_polar = shipped
    print(f"\nextract x 2 + match, GeoKey, {n} keypoints, {numba.get_num_threads()} numba threads (best / median of "
          f"{rounds}, ms; load "
          f"{os.getloadavg()[0]:.2f}, others {others:.2f} cores):")
    for name, (whole, walks) in times.items():
        print(f"{name:10s} pair {min(whole):6.1f} / {np.median(whole):6.1f}   its two walks {min(walks):6.1f} / "
              f"{np.median(walks):6.1f}")


if __name__ == "__main__":
    main()
