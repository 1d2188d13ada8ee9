"""tests/hang_guard.py: a test stuck with the GIL held, where pytest-timeout cannot reach it,
ends its process with every thread's stack, and under pytest-xdist the run goes on without it.

Each case runs pytest in a child process on a file whose first test waits on a mutex it holds,
through ``ctypes.PyDLL``, which keeps the GIL across the call: no signal ends the wait and no
Python code runs again, which is the hang the guard exists for, made certain."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.hang_guard import GRACE_S, limit_s

ROOT = Path(__file__).resolve().parents[1]

HANGS = """
import ctypes


def test_holds_the_gil():
    libc = ctypes.PyDLL(None)  # a PyDLL call keeps the GIL
    mutex = ctypes.create_string_buffer(64)  # PTHREAD_MUTEX_INITIALIZER is all zeros
    libc.pthread_mutex_lock(mutex)
    libc.pthread_mutex_lock(mutex)  # a normal mutex locked twice: no signal ends the wait


def test_after():
    assert 1 + 1 == 2
"""


def run_pytest(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / "test_stuck.py").write_text(HANGS)
    (tmp_path / "pytest.ini").write_text("[pytest]\ntimeout = 1\nhang_guard_grace = 2\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("DJANGO_SETTINGS_MODULE", None)
    command = [sys.executable, "-m", "pytest", "-p", "tests.hang_guard", "-p", "no:django",
               "-p", "no:cacheprovider", "-o", "addopts=", *args, "test_stuck.py"]  # fmt: skip
    # The guard ends the stuck test 3 s after it starts; the limit only stops a broken guard.
    return subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip


@pytest.mark.slow
def test_a_run_without_workers_ends_with_the_stacks(tmp_path: Path) -> None:
    result = run_pytest(tmp_path, "-n0")
    out = result.stdout + result.stderr
    assert result.returncode != 0
    assert "Timeout (0:00:03)!" in out
    assert "in test_holds_the_gil" in out  # the stack of the thread that holds the GIL


@pytest.mark.slow
def test_under_xdist_the_worker_ends_and_the_run_goes_on(tmp_path: Path) -> None:
    result = run_pytest(tmp_path, "-n", "1")
    out = result.stdout + result.stderr
    assert result.returncode == 1, out
    assert "crashed while running 'test_stuck.py::test_holds_the_gil'" in out
    assert "1 failed, 1 passed" in out
    assert "in test_holds_the_gil" in out


class FakeItem:
    """What :func:`limit_s` reads of a test: its timeout mark and the run's options."""

    def __init__(self, mark: pytest.Mark | None, option: float | None, ini: str) -> None:
        self.mark = mark
        self.config = SimpleNamespace(
            getoption=lambda name, default=None: option,
            getini=lambda name: {"timeout": ini, "hang_guard_grace": str(GRACE_S)}[name],
        )

    def get_closest_marker(self, name: str) -> pytest.Mark | None:
        return self.mark


def test_the_limit_is_the_timeout_plus_the_grace() -> None:
    assert limit_s(FakeItem(None, None, "600")) == 600 + GRACE_S
    assert limit_s(FakeItem(None, 20.0, "600")) == 20 + GRACE_S  # --timeout
    assert limit_s(FakeItem(pytest.mark.timeout(30).mark, 20.0, "600")) == 30 + GRACE_S
    assert limit_s(FakeItem(pytest.mark.timeout(timeout=45).mark, None, "600")) == 45 + GRACE_S
    assert limit_s(FakeItem(pytest.mark.timeout(0).mark, None, "600")) is None  # off
    assert limit_s(FakeItem(None, None, "0")) is None
