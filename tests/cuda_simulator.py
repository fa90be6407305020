"""Run a script under numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1), in a subprocess so that the
simulator, which must be switched on before numba.cuda is imported, does not leak into other tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SRC = str(Path(__file__).resolve().parents[1] / "src")


def run_simulated(script: str, *args: str) -> str:
    """Run the Python `script` (with `args` as sys.argv[1:]) under the CUDA simulator with this
    checkout's geofeat; fails the test with the script's last error lines unless it exits 0 and
    prints "ok". Returns its standard output."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    env["PYTHONPATH"] = SRC + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-c", script, *args], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "ok" in proc.stdout, proc.stderr[-3000:]
    return proc.stdout


#: Script lines that make `frame`, a small textured RGB-D frame on a gently waved surface (48 x 40,
#: the "clean" profile's scale), for the scripts that compare the GPU path with the CPU's.
SMALL_FRAME = r'''
import cv2, numpy as np
from geofeat.frame import RGBDFrame
H, W = 40, 48
K = np.array([[300.0, 0, 23.5], [0, 300.0, 19.5], [0, 0, 1]])
v, u = np.mgrid[0:H, 0:W].astype(float)
depth = (1.0 + 0.05 * np.sin(u / 5.0) * np.cos(v / 6.0) + 0.002 * u).astype(np.float32)
img = cv2.GaussianBlur(np.random.default_rng(0).random((H, W)).astype(np.float32), (0, 0), 1.5)
frame = RGBDFrame((img - img.min()) / (img.max() - img.min()), depth, K)
'''
