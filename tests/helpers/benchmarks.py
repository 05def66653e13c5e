"""Benchmarks are scripts, not package modules: their tests load them by path."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def loaded_benchmark(name: str) -> Iterator[ModuleType]:
    """benchmarks/NAME.py as a module, registered in sys.modules while in use (dataclasses look their module up);
    for a module-scoped fixture: `yield from loaded_benchmark("bench_x")`. benchmarks/ is on sys.path while it
    loads, as it is for a script run from there, so a benchmark can import its sibling modules."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    yield module
    del sys.modules[spec.name]
