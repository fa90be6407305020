"""Measure GeoBit matching accuracy against the ring spread sigma of the test pattern.

Run: python benchmarks/geobit_sigma.py   (about a minute on 2 cores)

Two tasks, correct nearest-neighbour rate under the min-over-rotations Hamming distance:
- kinect: the Kinect v1 demo frame matched into the same frame rolled by 90, 180, 270 degrees.
  Sources: the 51 landmarks + those of the 1000 strongest SIFT keypoints that have a SIFT keypoint
  of the rolled frame within 2 px of their true position; targets: the rolled landmarks + the 1000
  strongest SIFT keypoints of the rolled frame. Correct when the matched target lies within 2 px
  of the source's true position.
- sheet: 100 points of a flat textured sheet (1 m away) matched into the same sheet bent around a
  4 cm radius cylinder (tests/sheets.py), 3 textures; targets: the 100 bent points + the 1000
  strongest SIFT keypoints of the bent rendering; correct when within 2 px.
Each sigma is tried with 5 patterns (seeds 0..4); the table shows mean (min-max) in percent.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import geofeat  # noqa: E402
import sheets  # noqa: E402
from geofeat.descriptors.geobit import GeoBit  # noqa: E402
from geofeat.frame import rotate_points90  # noqa: E402
from geofeat.io import demo_data_dir, read_landmarks  # noqa: E402
from geofeat.keypoints import detect  # noqa: E402
from geofeat.matching import match  # noqa: E402

SIGMAS = (2.0, 3.2, 5.0, 7.0, 10.24, 14.0, 20.0)
SEEDS = range(5)
N_SIFT = 1000


def kinect_tasks():
    frame = geofeat.read_demo_frame()
    _, xy, _ = read_landmarks(demo_data_dir() / "cloud_1.csv")
    kp = detect(frame, n=N_SIFT, detector="sift").xy
    sources = np.concatenate([xy, kp])
    src = geofeat.polar_patches(frame, sources)
    tasks = []
    for k in (1, 2, 3):
        fk = frame.rotated90(k)
        targets = detect(fk, n=N_SIFT, detector="sift").xy
        truth = rotate_points90(sources, frame.shape, k)
        # keep sources with a detected counterpart within 2 px (all landmarks are kept: added below)
        d = np.linalg.norm(truth[:, None] - targets[None], axis=2).min(axis=1)
        keep = d <= 2.0
        keep[: len(xy)] = True
        targets = np.concatenate([rotate_points90(xy, frame.shape, k), targets])
        sub = geofeat.geodesic.polar.PolarPatches(
            src.keypoints[keep], src.values[keep], src.coords[keep], src.valid[keep],
            src.rings_reached[keep], src.points[keep], src.radius)
        tasks.append((sub, geofeat.polar_patches(fk, targets), truth[keep], targets))
    return tasks


def sheet_tasks(z0=1.0, bend_radius=0.04, u_max=0.035):
    tasks = []
    for tex_seed in range(3):
        tex = sheets.make_texture(tex_seed)
        flat, bent = sheets.render_flat(tex, z0=z0), sheets.render_bent(tex, z0=z0, bend_radius=bend_radius)
        uv = sheets.sample_material_points(100, seed=tex_seed, u_max=u_max)
        p0, p1 = sheets.project_flat(uv, z0=z0), sheets.project_bent(uv, z0=z0, bend_radius=bend_radius)
        distract = detect(bent, n=N_SIFT, detector="sift").xy
        targets = np.concatenate([p1, distract])
        tasks.append((geofeat.polar_patches(flat, p0), geofeat.polar_patches(bent, targets), p1, targets))
    return tasks


def accuracy(gb: GeoBit, tasks) -> float:
    correct = total = 0
    for src, dst, truth, targets in tasks:
        f0 = gb.describe(src.values, src.valid)
        f1 = gb.describe(dst.values, dst.valid)
        m = match(geofeat.features.Features(src.keypoints, f0, src.valid),
                  geofeat.features.Features(dst.keypoints, f1, dst.valid)).matches0
        ok = m >= 0
        err = np.full(len(m), np.inf)
        err[ok] = np.linalg.norm(targets[m[ok]] - truth[ok], axis=1)
        correct += int((err <= 2.0).sum())
        total += len(m)
    return 100.0 * correct / total


def main() -> None:
    tasks = {"kinect": kinect_tasks(), "sheet": sheet_tasks()}
    print(f"{'sigma':>6} | " + " | ".join(f"{name:>18}" for name in tasks))
    for sigma in SIGMAS:
        cells = []
        for name, tk in tasks.items():
            acc = np.array([accuracy(GeoBit(seed=s, sigma=sigma), tk) for s in SEEDS])
            cells.append(f"{acc.mean():6.1f} ({acc.min():5.1f}-{acc.max():5.1f})")
        print(f"{sigma:6.2f} | " + " | ".join(f"{c:>18}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
