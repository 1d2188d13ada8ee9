"""The benchmarks are scripts, not packages: :func:`load_bench` imports one for its tests."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

BENCH = Path(__file__).resolve().parents[2] / "bench"


@contextmanager
def load_bench(name: str) -> Iterator[ModuleType]:
    """``bench/<name>.py`` as a module, its folder on the path while it loads (its sibling
    benches import each other, as when run as scripts); forgotten afterwards."""
    spec = importlib.util.spec_from_file_location(f"{name}_under_test", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    added = str(BENCH) not in sys.path
    if added:
        sys.path.insert(0, str(BENCH))
    try:
        spec.loader.exec_module(module)
    finally:
        while added and str(BENCH) in sys.path:
            sys.path.remove(str(BENCH))
    try:
        yield module
    finally:
        del sys.modules[spec.name]
