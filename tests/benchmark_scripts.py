"""Import the scripts of benchmarks/ (not a package) in tests."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def import_benchmarks(*names: str) -> list[ModuleType]:
    """The modules benchmarks/NAME.py, imported with benchmarks/ on sys.path only while importing
    (their own imports of each other, such as `common`, resolve there)."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        return [importlib.import_module(name) for name in names]
    finally:
        sys.path.remove(str(BENCHMARKS))
