"""The first run after installing: how long numba takes to compile geofeat's kernels.

Runs `geofeat demo` (or `--job readme`: the README's Python example) in a child process with an empty
numba cache folder (`NUMBA_CACHE_DIR`), then again with the cache it filled, and prints both wall
times and the load average. With `--kernels`, the child also records numba's compile events and
prints the seconds spent compiling each geofeat kernel (a kernel's time includes the kernels it
calls that were compiled with it, so the column does not add up).

Run: PYTHONPATH=src .venv/bin/python benchmarks/bench_first_run.py [--job demo|readme] [--kernels]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Child process: optionally records numba's compile events, then runs the job.
CHILD = r"""
import collections, json, runpy, sys, time
seconds = collections.defaultdict(float)
if sys.argv[2] == "1":
    from numba.core import event

    class Compiles(event.Listener):
        def __init__(self):
            self.started = {}

        def on_start(self, ev):
            self.started[id(ev.data["dispatcher"]), str(ev.data["args"])] = time.perf_counter()

        def on_end(self, ev):
            fn = ev.data["dispatcher"].py_func
            start = self.started.pop((id(ev.data["dispatcher"]), str(ev.data["args"])))
            if fn.__module__.startswith("geofeat"):
                seconds[fn.__module__ + "." + fn.__qualname__] += time.perf_counter() - start

    event.register("numba:compile", Compiles())
if sys.argv[1] == "demo":
    from geofeat.cli import main
    main(["demo", "--out", sys.argv[3]])
else:
    runpy.run_path(sys.argv[3], run_name="__main__")
print("COMPILES " + json.dumps(seconds))
"""


def readme_example(folder: Path) -> Path:
    """The README's Python example as a script in `folder`, writing its .h5 file there."""
    text = (ROOT / "README.md").read_text()
    code = re.search(r"## In Python\n\n```python\n(.*?)```", text, re.S).group(1)
    path = folder / "readme_example.py"
    path.write_text(code.replace('"frame.h5"', repr(str(folder / "frame.h5"))))
    return path


def run_child(job: str, kernels: bool, cache: Path, folder: Path, tag: str) -> tuple[float, dict]:
    """Wall seconds of one child run with numba's cache in `cache`, and its compile seconds per kernel."""
    import json

    target = str(folder / f"demo-{tag}") if job == "demo" else str(readme_example(folder))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT / "src"))
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, job, "1" if kernels else "0", target], env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        sys.exit(f"the {job} run failed:\n{done.stderr[-3000:]}")
    line = [ln for ln in done.stdout.splitlines() if ln.startswith("COMPILES ")][-1]
    return wall, json.loads(line[len("COMPILES "):])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--job", choices=("demo", "readme"), default="demo")
    ap.add_argument("--kernels", action="store_true", help="print the compile seconds of each geofeat kernel")
    a = ap.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory() as tmp:
        folder, cache = Path(tmp), Path(tmp) / "numba-cache"
        first, compiles = run_child(a.job, a.kernels, cache, folder, "first")
        again, _ = run_child(a.job, False, cache, folder, "again")
    print(f"{a.job}: first run (empty numba cache) {first:.1f} s, again (cache filled) {again:.1f} s; "
          f"load average after: {os.getloadavg()[0]:.2f}")
    if a.kernels:
        print("compile seconds per geofeat kernel (callees compiled with a kernel count in its time too):")
        for name, seconds in sorted(compiles.items(), key=lambda kv: -kv[1]):
            if seconds >= 0.5:
                print(f"  {seconds:6.1f}  {name}")


if __name__ == "__main__":
    main()
