"""The layering rules hold and are live.

- import-linter's contracts (pyproject.toml) are kept: racing/ is a pure library, imports point
  one way (console -> leaderboard -> training -> racing), training's Django-free rooms import
  no Django, and only training.storage talks to MinIO.
- The console and the league use training through its services, selectors, models and small
  public helpers (training.catalog, training.errors, training.formatting), never its internals.
- The contracts are not vacuous: a copy of the project with one forbidden import added (Django
  in the RL core, a training internal in the console or the league...) breaks them.
- No import cycle among training's modules, function-local imports included (grimp sees them).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("racing", "training", "leaderboard", "console")
LINTER = Path(sys.executable).with_name("lint-imports")


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(LINTER), "--config", str(root / "pyproject.toml"), "--no-cache"],
        cwd=root,
        env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(root)},
        capture_output=True,
        text=True,
        timeout=180,
    )


def test_import_contracts_are_kept():
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


@pytest.mark.slow
@pytest.mark.parametrize(
    ("room", "line", "contract"),
    [
        ("training/rl", "import django.db", "import no Django"),
        ("training/rollout", "from training import models", "import no Django"),
        ("training/interchange", "import minio", "only training.storage talks to MinIO"),
        ("racing", "import celery", "racing is a pure library"),
        ("training/services", "from training import tasks", "interfaces > worker > services"),
        ("console", "from training.rl import presets", "console and league use training's"),
        ("console/views", "from training import sandbox", "console and league use training's"),
        ("leaderboard", "import training.storage", "console and league use training's"),
        ("leaderboard", "from training.worker import common", "console and league use training's"),
    ],
)
def test_a_forbidden_import_breaks_the_contracts(tmp_path, room, line, contract):
    copy = tmp_path / "project"
    copy.mkdir()
    shutil.copy(ROOT / "pyproject.toml", copy)
    for package in PACKAGES:
        shutil.copytree(
            ROOT / package, copy / package, ignore=shutil.ignore_patterns("__pycache__")
        )
    (copy / room / "contract_probe.py").write_text(f"{line}\n")
    result = lint_imports(copy)
    assert result.returncode != 0, result.stdout
    broken = [s for s in result.stdout.splitlines() if s.endswith("BROKEN")]
    assert any(contract in s for s in broken), result.stdout


def _imports(graph: grimp.ImportGraph, module: str) -> set[str]:
    """What ``module`` imports, less a package's imports of its own submodules (re-exports in
    an ``__init__``, which Python resolves without a cycle of the design)."""
    return {
        m for m in graph.find_modules_directly_imported_by(module)
        if not m.startswith(module + ".")
    }  # fmt: skip


def _cycles(graph: grimp.ImportGraph, modules: set[str]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), i.e. import cycles."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in _imports(graph, node) & modules:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                item = stack.pop()
                on_stack.discard(item)
                component.append(item)
                if item == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for module in sorted(modules):
        if module not in index:
            visit(module)
    return found


def test_no_import_cycle_among_training_modules():
    graph = grimp.build_graph("training")
    modules = set(graph.modules)
    assert len(modules) > 40  # the graph really holds training's modules
    assert _cycles(graph, modules) == []


def test_the_cycle_check_finds_a_cycle():
    graph = grimp.ImportGraph()
    for module in ("a", "b", "c"):
        graph.add_module(module)
    graph.add_import(importer="a", imported="b")
    graph.add_import(importer="b", imported="c")
    graph.add_import(importer="c", imported="a")
    assert _cycles(graph, {"a", "b", "c"}) == [["a", "b", "c"]]
