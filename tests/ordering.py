"""The longest test files first, so that no worker is left alone with a long file at the end.

pytest-xdist (``--dist loadfile``) hands each worker a whole file at a time, in the order of the
collection, unless it reorders them itself (by the number of tests: the default, turned off in
pyproject.toml with ``--no-loadscope-reorder``). A browser file of one test can take 90 s, so
taken last it kept one of a 2-core machine's workers busy while the other idled. Here every file
is ranked by what it took in a recorded run (``tests/durations.json``, seconds a file); a file
not recorded yet is ranked by its marks. A stale record only changes the order, never a result.

``pytest --record-durations tests/durations.json`` writes a new record from the run (setup, call
and teardown of every test, summed a file; every worker's reports reach the controller).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pytest

DURATIONS = Path(__file__).with_name("durations.json")
"""Seconds a test file took in a recorded run, by its path relative to the repository."""

# Seconds an unrecorded test is taken to take: a browser test starts a server and Chromium, a
# slow one trains or waits for a worker, the rest are quick.
BROWSER_S = 20.0
SLOW_S = 10.0
QUICK_S = 0.2


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--record-durations",
        metavar="PATH",
        default=None,
        help="write each test file's seconds in this run to PATH (JSON), for tests/ordering.py",
    )


def _guess(item: pytest.Item) -> float:
    if item.get_closest_marker("browser"):
        return BROWSER_S
    if item.get_closest_marker("slow"):
        return SLOW_S
    return QUICK_S


def _recorded() -> dict[str, float]:
    try:
        data = json.loads(DURATIONS.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {str(k): float(v) for k, v in data.items() if isinstance(v, int | float)}


def file_order(items: list[pytest.Item], recorded: dict[str, float]) -> list[pytest.Item]:
    """The items, whole files longest first (ties by path), each file's tests in their order."""
    files: dict[str, list[pytest.Item]] = defaultdict(list)
    for item in items:
        files[item.nodeid.split("::", 1)[0]].append(item)

    def cost(path: str) -> float:
        if path in recorded:
            return recorded[path]
        return sum(_guess(item) for item in files[path])

    ranked = sorted(files, key=lambda path: (-cost(path), path))
    return [item for path in ranked for item in files[path]]


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # Every worker collects and must order alike: the order depends only on the items and the
    # checked-in record.
    items[:] = file_order(items, _recorded())


class _Recorder:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.seconds: dict[str, float] = defaultdict(float)

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.seconds[report.nodeid.split("::", 1)[0]] += report.duration

    def pytest_sessionfinish(self) -> None:
        ranked = dict(sorted(self.seconds.items(), key=lambda kv: (-kv[1], kv[0])))
        self.path.write_text(json.dumps({k: round(v, 1) for k, v in ranked.items()}, indent=1))


def pytest_configure(config: pytest.Config) -> None:
    path = config.getoption("--record-durations")
    # The controller sees every worker's reports; a worker (``workerinput``) records nothing.
    if path and not hasattr(config, "workerinput"):
        config.pluginmanager.register(_Recorder(Path(path)), "racecraft-record-durations")
