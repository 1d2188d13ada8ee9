"""The hostile reward functions of tests/training/hostile/: each is refused or contained with a
clear error, and the host stays intact.

Files marked ``mode: bypass`` run with the Python layer switched off (no static check, full
builtins): the OS layers alone must contain them. Placeholders: @CANARY@ a path in a
writable temp dir that must not appear, @SECRET@ a readable file whose content must not leak,
@TARGET@ a file that must survive, @PORT@ a listening TCP port that must get no connection,
@REDIS_SOCKET@ the test Redis's unix socket (its keys must not change), @ROOT@ this checkout.
A ``# slow: yes`` line marks a case that needs its full time limit.
"""

from __future__ import annotations

import re
import socket
from dataclasses import dataclass
from pathlib import Path

import pytest
import redis

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.sandbox import SandboxLimits, check_source, evaluate_reward

HOSTILE_DIR = Path(__file__).parent / "hostile"
SECRET = "hunter2-canary-secret"
LIMITS = SandboxLimits(per_call_seconds=0.5, cpu_seconds=30, start_seconds=20)


@dataclass(frozen=True)
class HostileCase:
    name: str
    title: str
    mode: str
    expect: str
    match: str
    line: int | None
    slow: bool
    source: str


def _load(path: Path) -> HostileCase:
    text = path.read_text()
    meta = dict(re.findall(r"^# (\w+): ?(.*)$", text, flags=re.MULTILINE))
    return HostileCase(
        name=path.stem,
        title=meta["hostile"],
        mode=meta["mode"],
        expect=meta["expect"],
        match=meta.get("match", ""),
        line=int(meta["line"]) if "line" in meta else None,
        slow=meta.get("slow") == "yes",
        source=text,
    )


CASES = [_load(p) for p in sorted(HOSTILE_DIR.glob("*.py")) if p.name != "__init__.py"]


def test_the_suite_covers_enough() -> None:
    assert len(CASES) >= 130
    titles = " ".join(c.title + " " + c.source for c in CASES)
    for topic in [
        "import os",
        "import sys",
        "import subprocess",
        "import socket",
        "import ctypes",
        "import importlib",
        "__import__",
        "__builtins__",
        "__mro__",
        "__subclasses__",
        "np.load",
        "fromfile",
        "savetxt",
        "scipy.io",
        "open(",
        "create_connection",
        "fork",
        "while True",
        "sleep",
        "MemoryError",
        "f(n + 1)",
        "print(",
        "nan",
        "inf",
        "1e6",
        "'1.0'",
        "SystemExit",
        "KeyboardInterrupt",
        "signal",
        "threading",
        "params.clear",
        "environ",
        ".format(",
        "format_map",
        "match params",
        "case object(",
        "pickle",
        "prctl",
        "setrlimit",
        "/proc/self",
        "closerange",
        "clock_settime",
        "gc.get_objects",
        "ptrace",
        "io_uring",
        "AF_UNIX",
        "SOCK_DGRAM",
        "setsid",
        "execv",
    ]:
        assert topic in titles, topic
    assert sum(c.mode == "bypass" for c in CASES) >= 40


@pytest.fixture
def arena(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, redis_url: str):
    """Temp files for the placeholders, a listening port, a secret in our environment."""
    monkeypatch.setenv("RACECRAFT_TEST_SECRET", SECRET)
    secret = tmp_path / "secret.txt"
    secret.write_text(SECRET)
    target = tmp_path / "target.txt"
    target.write_text("keep me")
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    listener.setblocking(False)
    # Root ignores file permissions: show the directory really is writable for us, so that
    # "no file appeared" is not vacuous.
    probe = tmp_path / "probe"
    probe.write_text("x")
    probe.unlink()
    store = redis.Redis.from_url(redis_url)
    store.set("racecraft-hostile-canary", "keep")
    socket_path = redis_url.split("://", 1)[1].split("?")[0] if "unix" in redis_url else ""
    yield {
        "@CANARY@": str(tmp_path / "canary"),
        "@SECRET@": str(secret),
        "@TARGET@": str(target),
        "@PORT@": str(listener.getsockname()[1]),
        "@REDIS_SOCKET@": socket_path or str(tmp_path / "no-redis.sock"),
        "@ROOT@": str(Path(__file__).resolve().parents[3]),
        "dir": tmp_path,
        "listener": listener,
        "redis": store,
    }
    listener.close()
    store.delete("racecraft-hostile-canary")
    store.close()


@pytest.mark.parametrize(
    "case",
    [pytest.param(c, marks=pytest.mark.slow) if c.slow else c for c in CASES],
    ids=[c.name for c in CASES],
)
def test_hostile_function_is_refused_or_contained(case: HostileCase, arena: dict) -> None:
    source = case.source
    for key in ("@CANARY@", "@SECRET@", "@TARGET@", "@PORT@", "@REDIS_SOCKET@", "@ROOT@"):
        source = source.replace(key, arena[key])
    guarded = case.mode == "guarded"
    static_case = guarded and case.expect in ("SYNTAX_ERROR", "IMPORT_ERROR")
    if static_case:
        static = check_source(source)
        assert static and static[0].type == case.expect, static  # refused before running
        assert re.search(case.match, " | ".join(e.message for e in static)), static
        assert static[0].line is not None
    params = real_params()
    calls = 3 if case.expect == "OK" else 1
    with host_intact(arena["dir"], Path(__file__).parent):
        result = evaluate_reward(source, [params] * calls, limits=LIMITS, python_guards=guarded)
    errors = result.errors
    if case.expect == "OK":
        assert not errors, errors
        assert [o.value for o in result.outcomes] == [1.0] * calls
    else:
        assert errors, f"{case.name} was not stopped: {result.outcomes}"
        err = errors[0]
        assert err.type == case.expect, err
        if not static_case:  # the sandbox reports the first static error only
            assert re.search(case.match, err.message), err
        if case.line is not None:
            assert err.line == case.line
    # The effects never happened.
    assert not Path(arena["@CANARY@"]).exists()
    assert Path(arena["@TARGET@"]).read_text() == "keep me"
    everything = result.output + " ".join(e.message for e in errors)
    assert SECRET not in everything
    assert len(result.output) <= LIMITS.max_output_chars + 200
    with pytest.raises(BlockingIOError):
        arena["listener"].accept()
    assert params == real_params()  # the caller's params are untouched
    assert arena["redis"].get("racecraft-hostile-canary") == b"keep"  # no FLUSHALL, no DEL
