"""Tried for issue 21, not shipped: walk every other direction of the polar patch and interpolate
the directions in between, to halve the walk.

The walked directions are exactly `walk_polar`'s (the same angles, 2 pi a / n_angles for even a).
Direction a + 1 at ring i is put at c + (A_i - c + B_i - c) / (2 cos(delta / 2)), where c is the
keypoint's surface point, A_i and B_i the walked neighbours' samples at ring i, and delta their
angle: the midpoint of the arc between them, exact on a plane. Its rings reached are the smaller of
its neighbours'. The sample is projected with K and the patch is read there as usual.

It prints, per frame, the walk's time with every direction walked and with half of them (the
Kinect frame, best of `--repeats` in `--rounds` interleaved rounds, with the load average), and
the interpolated directions' distance to the walked ones (per direction, the largest over its
rings, pixels). With `--bench SEQS... --out DIR` it also runs `geofeat bench` on SEQS twice in this
process, once per f(.), and prints the paired difference of the matching score per descriptor (mean
over sequences of the per-sequence means, as the bench; 95 % bootstrap interval over sequences).

    PYTHONPATH=src python benchmarks/walk_interpolated_rays.py [--frames SEQ...] \
        [--bench out/difficulty/hard --out /tmp/halfrays --detector geokey --depth-profile kinect]
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import time
from pathlib import Path

import numpy as np
from numba import njit, prange

import geofeat
import geofeat.geodesic.polar as polar
from geofeat.geodesic.mesh import frame_mesh
from geofeat.geodesic.walk import walk_polar
from geofeat.io import read_sequence

from common import paired_by_sequence


@njit(cache=True, parallel=True)
def _interleave(walked, walked_coords, walked_reached, centre, K, samples, coords, reached):
    """Fill (N, R, 2 A2, .) outputs: even directions copied from the walked (N, R, A2, .) ones,
    odd directions interpolated between their two walked neighbours (module docstring)."""
    N, R, A2, _ = walked.shape
    w = 1.0 / (2.0 * math.cos(math.pi / A2))  # delta / 2 = (2 pi / A2) / 2
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for k in prange(N):
        for j in range(A2):
            b = (j + 1) % A2
            reached[k, 2 * j] = walked_reached[k, j]
            reached[k, 2 * j + 1] = min(walked_reached[k, j], walked_reached[k, b])
            for i in range(R):
                for d in range(3):
                    samples[k, i, 2 * j, d] = walked[k, i, j, d]
                px = centre[k, 0] + w * (walked[k, i, j, 0] + walked[k, i, b, 0] - 2.0 * centre[k, 0])
                py = centre[k, 1] + w * (walked[k, i, j, 1] + walked[k, i, b, 1] - 2.0 * centre[k, 1])
                pz = centre[k, 2] + w * (walked[k, i, j, 2] + walked[k, i, b, 2] - 2.0 * centre[k, 2])
                samples[k, i, 2 * j + 1, 0], samples[k, i, 2 * j + 1, 1], samples[k, i, 2 * j + 1, 2] = px, py, pz
                coords[k, i, 2 * j, 0] = walked_coords[k, i, j, 0]
                coords[k, i, 2 * j, 1] = walked_coords[k, i, j, 1]
                coords[k, i, 2 * j + 1, 0] = fx * px / pz + cx
                coords[k, i, 2 * j + 1, 1] = fy * py / pz + cy


def walk_half_the_rays(points, face_ok, normals, local, edges, starts, K, radius, n_angles, n_rings, max_crossings):
    """`walk_polar`'s signature and results, with the odd directions interpolated."""
    walked, walked_coords, walked_reached, centre = walk_polar(points, face_ok, normals, local, edges, starts, K,
                                                               radius, n_angles // 2, n_rings, max_crossings)
    N = len(starts)
    samples = np.empty((N, n_rings, n_angles, 3), np.float32)
    coords = np.empty((N, n_rings, n_angles, 2), np.float32)
    reached = np.zeros((N, n_angles), np.int32)
    _interleave(walked, walked_coords, walked_reached, centre, np.ascontiguousarray(K, np.float64), samples, coords,
                reached)
    return samples, coords, reached, centre


def patches(frame, keypoints, mesh, walk):
    polar.walk_polar = walk
    try:
        return polar.polar_patches(frame, keypoints, mesh=mesh)
    finally:
        polar.walk_polar = walk_polar


def frame_errors(name: str, frame) -> None:
    kp = geofeat.detect(frame, 2048, detector="geokey")
    mesh = frame_mesh(frame, "auto")
    exact, half = patches(frame, kp, mesh, walk_polar), patches(frame, kp, mesh, walk_half_the_rays)
    both = exact.valid & half.valid
    d = np.linalg.norm(exact.coords[both][:, :, 1::2] - half.coords[both][:, :, 1::2], axis=-1).max(1)
    full = (exact.rings_reached[both][:, 1::2] == exact.coords.shape[1])
    print(f"| {name} | {len(kp)} | {np.median(d):.2f} | {np.percentile(d, 90):.2f} | {np.mean(d > 1):.3f} | "
          f"{np.median(d[full]) if full.any() else float('nan'):.2f} | {np.mean(~full):.3f} |")


def bench_difference(seqs: list[str], out: Path, detector: str, descriptors: str, profile: str | None) -> None:
    from geofeat.cli import main as cli

    runs = {}
    for tag, walk in (("walked", walk_polar), ("interpolated", walk_half_the_rays)):
        polar.walk_polar = walk
        try:
            cli(["bench", *seqs, "--descriptors", descriptors, "--detector", detector, "--out", str(out / tag),
                 "--overwrite", *(["--depth-profile", profile] if profile else [])])
        finally:
            polar.walk_polar = walk_polar
        with open(out / tag / "results.csv") as fh:
            runs[tag] = {(r["sequence"], r["reference"], r["target"], r["descriptor"]): float(r["ms"])
                         for r in csv.DictReader(fh)}
    for desc in descriptors.split(","):
        print(paired_ms_line(runs, desc))


def paired_ms_line(runs: dict, desc: str) -> str:
    """The paired difference of `desc`'s MS, interpolated minus walked (`runs`: {tag: {(sequence,
    reference, target, descriptor): MS}}), as `geofeat bench` averages (mean over sequences of the
    per-sequence means), with its 95 % bootstrap interval over sequences (`common.paired_by_sequence`:
    the pairs of a sequence are not independent)."""
    keys = [k for k in runs["walked"] if k[3] == desc and k in runs["interpolated"]]
    p = paired_by_sequence(keys, [runs["walked"][k] for k in keys], [runs["interpolated"][k] for k in keys])
    return (f"{desc}: MS walked {p['a']:.3f}, interpolated {p['b']:.3f}, paired difference {p['diff']:+.4f} "
            f"[{p['low']:+.4f}, {p['high']:+.4f}] (95 % bootstrap over {p['sequences']} sequences, {p['pairs']} pairs)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", nargs="*", default=[], help="sequences whose last target frame is also measured")
    ap.add_argument("--bench", nargs="*", default=[], help="sequences to run `geofeat bench` on, both ways")
    ap.add_argument("--out", type=Path, default=Path("/tmp/walk_interpolated_rays"))
    ap.add_argument("--detector", default="geokey")
    ap.add_argument("--descriptors", default="geopatch,geobit")
    ap.add_argument("--depth-profile", default=None, help="passed to `geofeat bench` (default: its own)")
    a = ap.parse_args()

    frame = geofeat.read_demo_frame()
    kp = geofeat.detect(frame, 2048, detector="geokey")
    mesh = frame_mesh(frame, "auto")
    best = {"walked": math.inf, "interpolated": math.inf}
    patches(frame, kp, mesh, walk_half_the_rays)  # compile
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    for _ in range(a.rounds):
        for tag, walk in (("walked", walk_polar), ("interpolated", walk_half_the_rays)):
            for _ in range(a.repeats):
                t = time.perf_counter()
                patches(frame, kp, mesh, walk)
                best[tag] = min(best[tag], time.perf_counter() - t)
    print(f"Kinect frame, {len(kp)} GeoKey keypoints, polar_patches with the mesh reused: every direction walked "
          f"{best['walked'] * 1e3:.1f} ms, half of them {best['interpolated'] * 1e3:.1f} ms "
          f"(ratio {best['interpolated'] / best['walked']:.2f}); load average after {os.getloadavg()[0]:.2f}")
    print("\n| frame | keypoints | interpolated direction's error, median px | 90th pct | share > 1 px "
          "| median where the walked direction reaches every ring | share that stops earlier |")
    print("|---|---|---|---|---|---|---|")
    frame_errors("Kinect (shipped)", frame)
    for folder in a.frames:
        seq = read_sequence(folder)
        frame_errors(f"{Path(folder).parent.name}/{Path(folder).name}, {seq.targets[-1]}", seq.frame(seq.targets[-1]))
    if a.bench:
        print()
        bench_difference(a.bench, a.out, a.detector, a.descriptors, a.depth_profile)


if __name__ == "__main__":
    main()
