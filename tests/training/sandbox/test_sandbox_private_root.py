"""Issue 52 (kernel layers, part B): a lookup finds nothing Landlock does not let it read.

``stat()`` is no Landlock right, so before the sandbox had a root of its own reward code found
``/etc/shadow``'s size and time, the project's ``var/secret_key`` and every host process under
``/proc/<pid>``. Each test runs raw code with the Python guard off and compares what ``stat``
finds inside with what it finds on the host, outside the sandbox.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path

import psutil
import pytest

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.sandbox import SandboxLimits, SandboxUnavailable, evaluate_reward, isolation_support
from training.sandbox.requirements import ALLOW_WEAK_ENV, SIMULATE_ENV

ROOT = Path(__file__).resolve().parents[3]
LIMITS = SandboxLimits(per_call_seconds=10.0, cpu_seconds=60)

LOOKUPS = """
import os

def reward_function(params):
    found = []  # in the order of PATHS (the output is scrubbed of the project's paths)
    for path in PATHS:
        try:
            found.append(os.stat(path).st_size)
        except OSError as exc:
            found.append(f"errno {exc.errno}")
    pids = []
    for pid in HOST_PIDS:
        try:
            os.stat(f"/proc/{pid}")
            pids.append(pid)
        except OSError:
            pass
    print(repr({"found": found, "pids": pids, "own": os.path.exists("/proc/self/stat")}))
    if not LATE_IMPORT:  # without Landlock, seccomp refuses every open()
        return 1.0
    import colorsys  # a late import still reads the standard library

    return colorsys.rgb_to_hsv(1.0, 0.0, 0.0)[1]
"""


@pytest.fixture(autouse=True)
def _closed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ALLOW_WEAK_ENV, raising=False)
    monkeypatch.delenv(SIMULATE_ENV, raising=False)


@pytest.fixture
def secret(tmp_path: Path) -> Path:
    """A stand-in for ``var/secret_key``: a file the sandbox may not read, next to one it may
    (``tmp_path/allowed`` is given as an extra read path)."""
    (tmp_path / "allowed").mkdir()
    (tmp_path / "allowed" / "table.csv").write_text("1,2\n")
    path = tmp_path / "secret_key"
    path.write_text("s3cret" * 100)
    return path


def _lookups(secret: Path, disabled: tuple[str, ...] = ()) -> tuple[dict, dict, list[str]]:
    """What stat finds inside the sandbox (and its layers), and the paths it was asked for."""
    paths = [
        "/etc/shadow",
        "/etc/passwd",
        "/etc",
        "/home",
        str(ROOT / "var" / "secret_key"),
        str(ROOT / "manage.py"),
        str(secret),
        str(secret.parent / "allowed" / "table.csv"),
        str(ROOT / "training" / "sandbox" / "rootfs.py"),
        "/usr/lib",
    ]
    host_pids = [pid for pid in psutil.pids() if pid != 1]
    late = "landlock" not in disabled
    source = f"PATHS = {paths!r}\nHOST_PIDS = {host_pids!r}\nLATE_IMPORT = {late}\n" + LOOKUPS
    limits = SandboxLimits(
        per_call_seconds=10.0, cpu_seconds=60, read_paths=(str(secret.parent / "allowed"),)
    )
    with host_intact(secret.parent):
        result = evaluate_reward(
            source, [real_params()], limits=limits, python_guards=False, disabled_layers=disabled
        )
    assert [o.value for o in result.outcomes] == [1.0], result.outcomes
    seen = ast.literal_eval(result.output.strip().splitlines()[-1])
    return seen, result.layers, paths


@pytest.mark.parametrize("disabled", ["none", "landlock", "namespaces"])
def test_stat_finds_nothing_of_the_host_beyond_the_read_paths(disabled: str, secret: Path) -> None:
    """With every layer, and with the mount namespace left alone without Landlock (seccomp then
    refuses every open, never a stat) or without the PID namespace (then it has no /proc)."""
    other = {"landlock": "seccomp", "namespaces": "seccomp"}.get(disabled)
    if other and not isolation_support().get(other, "").startswith("active"):
        pytest.skip(f"{other} is not available here to stand in")
    off = () if disabled == "none" else (disabled,)
    seen, layers, paths = _lookups(secret, off)
    assert layers["mount_namespace"] == "active"
    found = dict(zip(paths, seen["found"], strict=True))
    hidden = [p for p in paths[:7] if os.path.exists(p)]
    assert len(hidden) >= 5  # the host has them (the project's var/ may not exist here)
    for path in hidden:
        assert found[path] == "errno 2", (path, found[path])  # ENOENT: no size, no time
    # What it may read is still there, where it was, with the host's size.
    for path in paths[7:]:
        assert found[path] == os.stat(path).st_size, path
    # Host processes by pid: 151 of them before this root (issue 52); none now.
    assert len(psutil.pids()) > 10
    assert seen["pids"] == []
    # Its own /proc: a fresh one of its PID namespace, or none without that namespace.
    assert seen["own"] is (disabled != "namespaces")


def test_without_a_mount_namespace_nothing_runs(secret: Path) -> None:
    """Fail closed, for real: the layer switched off (tests only) leaves the protection
    missing, and the code is never loaded."""
    with pytest.raises(SandboxUnavailable) as caught:
        _lookups(secret, ("mount_namespace",))
    assert caught.value.missing == ("no_host_lookups",)
    assert "/etc/shadow" in str(caught.value) and "pivot_root" in str(caught.value)


def test_the_operator_can_accept_running_without_it(secret: Path, monkeypatch) -> None:
    """RACECRAFT_ALLOW_WEAK_SANDBOX=1 runs it, as for other missing layers: then the host's
    files can be looked up (though still not opened: Landlock)."""
    monkeypatch.setenv(ALLOW_WEAK_ENV, "1")
    seen, layers, _ = _lookups(secret, ("mount_namespace",))
    assert layers["mount_namespace"] == "disabled (test only)"
    assert seen["found"][6] == secret.stat().st_size  # the secret's size, seen
