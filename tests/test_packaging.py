"""geofeat as a user gets it from `pip install`: the wheel and sdist built from this tree, the
command line started from another folder, and optional packages (onnxruntime, dask) missing."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

import geofeat

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(geofeat.__file__).resolve().parent

#: What the code loads from geofeat/data (weights, the GeoBit pattern, the demo frame, textures).
DATA_FILES = ["geopatch.pt", "geopatch.onnx", "geopatch_int8.onnx", "geokey.npz", "geobit_pattern.npz",
              "tfeat_sim.pt", "logpolar_sim.pt", "kinect_example/cloud_1-rgb.png",
              "kinect_example/cloud_1-depth.png", "kinect_example/intrinsics.xml", "kinect_example/cloud_1.csv",
              "kinect_example/LICENSE", "textures/SOURCES.md"]


def _env() -> dict:
    """The environment of a subprocess that imports the geofeat under test (source tree or installed)."""
    path = os.pathsep.join(filter(None, [str(PACKAGE.parent), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path}


# ---------------------------------------------------------------- the command line, from another folder
def test_python_dash_m_geofeat_runs_the_command_line(tmp_path):
    """`python -m geofeat` failed ("'geofeat' is a package and cannot be directly executed"): only
    `python -m geofeat.cli` worked."""
    run = subprocess.run([sys.executable, "-m", "geofeat", "--help"], cwd=tmp_path, env=_env(),
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("usage: geofeat") and "simulate" in run.stdout
    assert list(tmp_path.iterdir()) == []


def test_version_option_prints_the_package_version(tmp_path, capsys):
    """`geofeat --version` was an error (exit 2, the usage)."""
    from geofeat.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"geofeat {geofeat.__version__}"


def test_pyproject_version_is_the_package_version():
    text = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'^version = "([^"]+)"', text, re.M).group(1) == geofeat.__version__


