"""Speed of the cloth simulator: simulate + render frames per second at 640 x 480, next to the
cost of writing (OpenCV PNG encoding of the colour and depth images, and the ground-truth npz).

    .venv/bin/python benchmarks/bench_sim.py [--frames 60] [--width 640 --height 480]
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from geofeat.sim.cloth import ClothConfig
from geofeat.sim.scenes import ClothScene
from geofeat.sim.textures import packaged_texture_dir, read_texture
from geofeat.sim.writer import encode_depth, save_npz, simulate_sequence


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--steps-per-frame", type=int, default=6)
    a = ap.parse_args()
    tex = read_texture(packaged_texture_dir() / "kodak_kodim23.jpg")

    # warm-up (numba compilation / cache load)
    warm = ClothScene("deform", 2, np.random.default_rng(0), tex, (a.height, a.width))
    for _ in warm.frames():
        pass

    scene = ClothScene("deform", a.frames, np.random.default_rng(1), tex, (a.height, a.width),
                       steps_per_frame=a.steps_per_frame)
    t_sim = t_render = 0.0
    frames = []
    for f in range(a.frames):
        t0 = time.perf_counter()
        if f:
            scene.advance(scene.params.steps_per_frame)
        t1 = time.perf_counter()
        fr = scene.render_frame(f)
        t2 = time.perf_counter()
        t_sim += t1 - t0
        t_render += t2 - t1
        if f < 10:
            frames.append(fr)
    n = a.frames
    t_png = t_npz = 0.0
    for fr in frames:
        t0 = time.perf_counter()
        cv2.imencode(".png", fr.image)
        cv2.imencode(".png", encode_depth(fr.depth))
        t1 = time.perf_counter()
        save_npz(io.BytesIO(), uv=fr.render.uv, vertices=fr.vertices, R=fr.R, t=fr.t)
        t2 = time.perf_counter()
        t_png += t1 - t0
        t_npz += t2 - t1
    m = len(frames)
    # reference in the same process: the same solver with one block, i.e. serial sweeps
    serial = ClothScene("deform", a.frames, np.random.default_rng(1), tex, (a.height, a.width),
                        steps_per_frame=a.steps_per_frame, cloth_config=ClothConfig(solver_blocks=1))
    t0 = time.perf_counter()
    for _ in range(n - 1):
        serial.advance(serial.params.steps_per_frame)
    t_serial = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        simulate_sequence(Path(tmp) / "s", "deform", n_frames=30, seed=1, texture=packaged_texture_dir() / "kodak_kodim23.jpg",
                          width=a.width, height=a.height, progress=False, steps_per_frame=a.steps_per_frame)
        t_full = time.perf_counter() - t0
    print(f"machine: {os.cpu_count()} CPUs (nproc), {cpu_model()}")
    print(f"frame {a.width}x{a.height}, grid 80x60, {a.steps_per_frame} steps per frame of "
          f"{scene.config.substeps} sub-steps x (forward + backward sweep), {n} frames")
    print(f"simulate      {1000 * t_sim / max(n - 1, 1):7.1f} ms/frame")
    print(f"  serial sweeps (1 block) {1000 * t_serial / max(n - 1, 1):7.1f} ms/frame: "
          f"block-parallel is {t_serial / max(t_sim, 1e-9):.2f}x faster")
    print(f"render        {1000 * t_render / n:7.1f} ms/frame")
    print(f"sim + render  {1000 * (t_sim + t_render) / n:7.1f} ms/frame = {n / (t_sim + t_render):5.1f} frames/s (goal >= 20)")
    print(f"OpenCV PNG encode (rgb + depth) {1000 * t_png / m:7.1f} ms/frame")
    print(f"ground-truth npz (deflate-1)    {1000 * t_npz / m:7.1f} ms/frame")
    print(f"simulate_sequence end to end (30 frames, landmarks, files): {t_full:.2f} s = {30 / t_full:.1f} frames/s")


if __name__ == "__main__":
    main()
