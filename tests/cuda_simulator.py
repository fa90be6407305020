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
