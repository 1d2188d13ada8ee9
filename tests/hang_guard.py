"""A test that hangs with the GIL held ends its own process, not the whole run.

pytest-timeout fails a test that overruns its ``timeout``, but by Python code (a signal handler
or a timer thread) that runs only once the interpreter gets the GIL. A thread stuck in C code
with the GIL held stops it for ever, and the run with it: the README's test command once sat at
98 % with a worker idle in a test, its main thread waiting for the GIL, and pytest-timeout never
fired. faulthandler's watchdog is a C thread that needs no GIL. Armed for each test at the
test's timeout plus :data:`GRACE_S`, it writes every thread's stack to the process's standard
error and ends the process: pytest-xdist then reports the test as failed ("worker crashed") and
starts a new worker for the rest, and a run without workers (``-n0``) ends with the stacks.
pytest-timeout still stops every test it can reach, first, with its usual report.
"""

from __future__ import annotations

import faulthandler
import os
from collections.abc import Iterator

import pytest

GRACE_S = 60.0
"""Seconds past the test's timeout before the process is ended (``hang_guard_grace`` in the
ini file sets another): pytest-timeout gets its chance first."""

_stderr: list[int] = []  # a duplicate of fd 2, made once: pytest's capture swaps sys.stderr


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addini("hang_guard_grace", "seconds past a test's timeout before its process ends",
                  default=str(GRACE_S))  # fmt: skip


def pytest_configure(config: pytest.Config) -> None:
    if not _stderr:
        _stderr.append(os.dup(2))


def limit_s(item: pytest.Item) -> float | None:
    """The test's timeout (its ``timeout`` mark, else ``--timeout``, else the ini's) plus the
    grace; ``None`` where no timeout applies."""
    marker = item.get_closest_marker("timeout")
    timeout = None
    if marker is not None:
        timeout = marker.kwargs.get("timeout", marker.args[0] if marker.args else None)
    if timeout is None:
        timeout = item.config.getoption("timeout", None)
    if timeout is None:
        try:
            timeout = item.config.getini("timeout")
        except ValueError:  # pytest-timeout is not installed
            return None
    try:
        seconds = float(timeout)
    except (TypeError, ValueError):
        return None
    if seconds <= 0:
        return None
    return seconds + float(item.config.getini("hang_guard_grace"))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    limit = limit_s(item)
    if limit is None or not _stderr:
        yield
        return
    faulthandler.dump_traceback_later(limit, exit=True, file=_stderr[0])
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()
