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


# ---------------------------------------------------------------- the wheel and the sdist
@pytest.fixture(scope="module")
def dists(tmp_path_factory):
    """The wheel and sdist that setuptools builds from the files git would commit (tracked, or
    untracked and not ignored), in a copy of the tree: nothing is written into the checkout."""
    # pyproject's build-system (PEP 639 licence fields); the [test] extra asks for it
    pytest.importorskip("setuptools", minversion="77")
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                            capture_output=True)
    if listed.returncode != 0:
        pytest.skip("needs the git checkout")
    tree, out = tmp_path_factory.mktemp("tree"), tmp_path_factory.mktemp("dist")
    for name in filter(None, listed.stdout.decode().split("\0")):
        if (ROOT / name).is_file():
            (tree / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, tree / name)
    # (build_meta rewrites sys.argv: the folder is read first)
    code = "import sys; from setuptools import build_meta as b; d = sys.argv[1]; b.build_wheel(d); b.build_sdist(d)"
    run = subprocess.run([sys.executable, "-c", code, str(out)], cwd=tree, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    (wheel,), (sdist,) = out.glob("*.whl"), out.glob("*.tar.gz")
    with zipfile.ZipFile(wheel) as z:
        wheel_names = z.namelist()
        entry_points = z.read(next(n for n in wheel_names if n.endswith(".dist-info/entry_points.txt"))).decode()
    with tarfile.open(sdist) as t:
        sdist_names = [m.name.split("/", 1)[1] for m in t.getmembers() if m.isfile()]
    return {"wheel": wheel_names, "entry_points": entry_points, "sdist": sdist_names,
            "tree": sorted(p.relative_to(tree / "src").as_posix() for p in (tree / "src" / "geofeat").rglob("*")
                           if p.is_file())}


def test_wheel_ships_every_module_and_data_file_and_nothing_else(dists):
    names = set(dists["wheel"])
    package = {n for n in names if n.startswith("geofeat/")}
    assert package == set(dists["tree"])  # every module and data file of src/geofeat, nothing more
    for name in DATA_FILES:
        assert f"geofeat/data/{name}" in names
    assert len([n for n in names if n.startswith("geofeat/data/textures/") and n.endswith(".jpg")]) >= 10
    assert "geofeat/__main__.py" in names and "geofeat/cli/__main__.py" in names
    shipped = [n for n in names if not n.startswith("geofeat-")]
    assert not [n for n in shipped if not n.startswith("geofeat/")]  # no tests/, benchmarks/, docs/
    assert not [n for n in names if "__pycache__" in n or n.endswith((".pyc", ".nbi", ".nbc"))]
    assert re.search(r"^geofeat = geofeat\.cli:main$", dists["entry_points"], re.M)


def test_sdist_builds_a_complete_package_and_no_test_that_cannot_import(dists):
    """The sdist carried tests/test_*.py without the helper modules they import (surfaces.py,
    sheets.py): a test suite that failed at collection."""
    names = set(dists["sdist"])
    assert {f"src/{n}" for n in dists["tree"]} <= names
    assert {"pyproject.toml", "README.md", "LICENSE", "PKG-INFO"} <= names
    local = {p.stem for p in (ROOT / "tests").glob("*.py")}
    for name in sorted(n for n in names if n.startswith("tests/") and n.endswith(".py")):
        text = (ROOT / name).read_text()
        imported = set(re.findall(r"^\s*(?:from|import) (\w+)", text, re.M)) & local
        missing = sorted(m for m in imported if f"tests/{m}.py" not in names)
        assert not missing, f"{name} imports {missing}, which the sdist lacks"


# ---------------------------------------------------------------- optional packages missing
@pytest.fixture
def no_onnxruntime(monkeypatch):
    from geofeat.descriptors import geopatch
    from geofeat.descriptors.geopatch_onnx import BACKEND_ENV

    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import fails, find_spec says None
    monkeypatch.delenv(BACKEND_ENV, raising=False)
    monkeypatch.setattr(geopatch, "_warned_no_onnxruntime", False, raising=False)
    return geopatch


def test_without_onnxruntime_the_default_falls_back_to_torch_and_says_so_once(no_onnxruntime):
    """Without onnxruntime the shipped weights silently ran on torch (descriptors differing from the
    default int8 backend's, several times slower)."""
    with pytest.warns(RuntimeWarning, match="onnxruntime is not installed.*run on torch"):
        assert no_onnxruntime.resolve_backend(None, None, "cpu") == "torch"
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert no_onnxruntime.resolve_backend(None, None, "cpu") == "torch"
        assert no_onnxruntime.resolve_backend("torch", None, "cpu") == "torch"


@pytest.mark.parametrize("backend", ["onnx", "onnx-int8"])
def test_onnx_backend_without_onnxruntime_names_the_package(no_onnxruntime, backend):
    """backend='onnx-int8' without onnxruntime was a ModuleNotFoundError from deep inside (a traceback
    from the command line), where a missing openvino is a one-line ValueError."""
    with pytest.raises(ValueError, match=f"backend: {backend} needs the onnxruntime package"):
        no_onnxruntime.GeoPatch(backend=backend)


def _two_frame_demo_sequence(tmp_path):
    """The demo frame twice (reference and target), as a sequence folder."""
    from geofeat.io import demo_data_dir

    seq = tmp_path / "seq"
    seq.mkdir()
    for name in ("cloud_1-rgb.png", "cloud_1-depth.png", "intrinsics.xml"):
        shutil.copy(demo_data_dir() / name, seq / name)
    shutil.copy(seq / "cloud_1-rgb.png", seq / "cloud_2-rgb.png")
    shutil.copy(seq / "cloud_1-depth.png", seq / "cloud_2-depth.png")
    return seq


def test_bench_scheduler_without_dask_is_one_error_before_anything_is_written(tmp_path, monkeypatch, capsys):
    """`geofeat bench --scheduler ADDR` without dask wrote config.json and results.csv, then died in a
    ModuleNotFoundError traceback."""
    from geofeat.cli import main

    seq = _two_frame_demo_sequence(tmp_path)
    monkeypatch.setitem(sys.modules, "dask", None)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    out = tmp_path / "out"
    assert main(["bench", str(seq), "--descriptors", "orb", "--scheduler", "tcp://127.0.0.1:9", "--out", str(out)]) == 2
    assert "geofeat[dask]" in capsys.readouterr().err
    assert not out.exists()


def test_bench_scheduler_address_that_is_not_one_names_the_option(tmp_path, capsys):
    """`--scheduler foo` ended on dask's "missing port number in address 'foo'", naming no option."""
    pytest.importorskip("dask.distributed")
    from geofeat.cli import main

    seq = _two_frame_demo_sequence(tmp_path)
    assert main(["bench", str(seq), "--descriptors", "orb", "--scheduler", "foo", "--out", str(tmp_path / "out")]) == 2
    assert "scheduler: cannot reach a Dask scheduler at 'foo'" in capsys.readouterr().err
