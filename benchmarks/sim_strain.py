"""How isometric the simulated cloth stays: edge strain |d - rest| / rest over random scenes, for the
default solver (12 Verlet sub-steps, one symmetric Gauss-Seidel pass each) and, in the same process,
the paper's scheme (one Verlet step, then 12 symmetric passes = 24 sweeps), which costs the same.

    .venv/bin/python benchmarks/sim_strain.py [--seeds 12] [--frames 30]

Per solver: the worst structural (kind 0) and triangle-diagonal (kind 1) strain over all frames,
the largest per-frame 99th and 99.9th percentiles, the share of frames with any structural edge
beyond 2 %, and the simulation time per frame (6 steps).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from geofeat.sim.cloth import ClothConfig
from geofeat.sim.scenes import ClothScene
from geofeat.sim.textures import procedural_texture

SOLVERS = {
    "small steps (12 sub-steps x 1 pass)": ClothConfig(),
    "paper (1 step x 12 passes)": ClothConfig(substeps=1, passes=12),
}


def strain_stats(config: ClothConfig, seeds: int, frames: int) -> dict[str, float]:
    rows, t_sim = [], 0.0
    for seed in range(seeds):
        scene = ClothScene("deform", 2, np.random.default_rng(seed), procedural_texture(np.random.default_rng(0)),
                           size=(60, 80), cloth_config=config)
        for _ in range(frames):
            t0 = time.perf_counter()
            scene.advance(scene.params.steps_per_frame)
            t_sim += time.perf_counter() - t0
            s0, s1 = scene.cloth.strain(0), scene.cloth.strain(1)
            rows.append((s0.max(), np.percentile(s0, 99), np.percentile(s0, 99.9), s1.max()))
    r = np.array(rows)
    return {"max0": r[:, 0].max(), "p99": r[:, 1].max(), "p999": r[:, 2].max(), "max1": r[:, 3].max(),
            "over2": (r[:, 0] > 0.02).mean(), "ms": 1000 * t_sim / len(r)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--frames", type=int, default=30)
    a = ap.parse_args()
    strain_stats(ClothConfig(), 1, 1)  # warm-up: numba cache load
    print(f"{a.seeds} deform scenes x {a.frames} frames, 80 x 60 particles, 6 steps per frame")
    print("| solver | worst structural | per-frame p99 | per-frame p99.9 | worst diagonal | frames > 2 % | ms / frame |")
    print("|---|---|---|---|---|---|---|")
    for name, config in SOLVERS.items():
        s = strain_stats(config, a.seeds, a.frames)
        print(f"| {name} | {s['max0']:.2%} | {s['p99']:.2%} | {s['p999']:.2%} | {s['max1']:.2%} | "
              f"{s['over2']:.1%} | {s['ms']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
