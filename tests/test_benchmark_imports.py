"""The scripts of benchmarks/ name only what geofeat has: a rename in the package left
`bench_sim.py` importing `encode_depth_mm`, which no longer existed, and the script failed on import
with no test noticing."""

from __future__ import annotations

import ast
import importlib

import pytest

from benchmark_scripts import BENCHMARKS

SCRIPTS = sorted(BENCHMARKS.glob("*.py"))


def geofeat_imports(path) -> list[tuple[str, str]]:
    """(module, name) of every `from geofeat... import name` in the script at `path` (any depth)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and \
                node.module.split(".")[0] == "geofeat":
            found += [(node.module, alias.name) for alias in node.names if alias.name != "*"]
    return found


@pytest.mark.parametrize("script", SCRIPTS, ids=[p.name for p in SCRIPTS])
def test_every_geofeat_name_a_benchmark_imports_exists(script):
    missing = []
    for module, name in geofeat_imports(script):
        mod = importlib.import_module(module)
        if not hasattr(mod, name):
            try:
                importlib.import_module(f"{module}.{name}")  # a submodule
            except ImportError:
                missing.append(f"{module}.{name}")
    assert not missing, f"{script.name} imports names geofeat does not have: {missing}"
