"""Each OS layer holds on its own: attacks run with the Python layer off and one more layer
switched off at a time, and are still contained. Also: a caller without root privileges,
and the rollout mode that allows threads but no processes."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.sandbox import SandboxLimits, evaluate_reward, isolation_support, landlock
from training.sandbox.requirements import ALLOW_WEAK_ENV

LIMITS = SandboxLimits(per_call_seconds=1.0, cpu_seconds=30)

ATTACKS = {
    "write": "open(CANARY, 'w').write('x')",
    "read": "return float(len(open(SECRET).read()))",
    "fork": "pid = os.fork()\n    if pid == 0:\n        os._exit(0)",
    "connect": "socket.create_connection(('127.0.0.1', PORT), timeout=0.5)",
    # The host's pid (in the sandbox's own PID namespace getppid() is 0: it has no parent).
    "kill_parent": "os.kill(HOST_PID, signal.SIGTERM)",
    "environment": "assert 'RACECRAFT_LAYER_SECRET' not in os.environ\n    raise OSError('clean')",
}


def _source(body: str, arena: dict) -> str:
    return (
        "import os, signal, socket\n"
        f"CANARY, SECRET, PORT = {arena['canary']!r}, {arena['secret']!r}, {arena['port']}\n"
        f"HOST_PID = {os.getpid()}\n\n"
        f"def reward_function(params):\n    {body}\n    return 1.0\n"
    )


@pytest.fixture
def arena(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("RACECRAFT_LAYER_SECRET", "s3cret")
    secret = tmp_path / "secret"
    secret.write_text("s3cret")
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    listener.setblocking(False)
    yield {
        "canary": str(tmp_path / "canary"),
        "secret": str(secret),
        "port": listener.getsockname()[1],
        "dir": tmp_path,
        "listener": listener,
    }
    listener.close()


def _assert_contained(result, arena: dict) -> None:
    assert result.errors, result.outcomes
    assert not Path(arena["canary"]).exists()
    assert "s3cret" not in result.output + " ".join(e.message for e in result.errors)
    with pytest.raises(BlockingIOError):
        arena["listener"].accept()


@pytest.mark.parametrize("disabled", ["none", "landlock", "seccomp", "namespaces", "cgroup_pids"])
@pytest.mark.parametrize("attack", list(ATTACKS))
def test_attack_is_contained_with_a_layer_switched_off(
    attack: str, disabled: str, arena: dict, monkeypatch: pytest.MonkeyPatch
) -> None:
    if disabled == "seccomp" and attack == "kill_parent" and landlock.abi_version() < 6:
        pytest.skip("without seccomp, only Landlock ABI 6 scopes signals")
    if disabled == "seccomp" and landlock.abi_version() < 1:
        pytest.skip("no Landlock on this kernel: seccomp is the only filesystem layer")
    if disabled == "seccomp":  # inotify and the page cache have no other wall (issue 52)
        monkeypatch.setenv(ALLOW_WEAK_ENV, "1")
    off = () if disabled == "none" else (disabled,)
    with host_intact(arena["dir"]):
        result = evaluate_reward(
            _source(ATTACKS[attack], arena),
            [real_params()],
            limits=LIMITS,
            python_guards=False,
            disabled_layers=off,
        )
    for name in off:
        assert result.layers[name] == "disabled (test only)"
    if disabled == "seccomp" and attack == "kill_parent":
        # The host's pid names no process in the sandbox's PID namespace, or is refused.
        assert "ProcessLookupError" in result.errors[0].message or "PermissionError" in (
            result.errors[0].message
        )
    if disabled == "seccomp" and attack == "fork" and os.geteuid() == 0:
        assert result.layers["cgroup_pids"] == "active"  # root ignores RLIMIT_NPROC
    _assert_contained(result, arena)


def test_without_landlock_seccomp_refuses_every_open(arena: dict) -> None:
    body = "import colorsys"  # a late import needs open()
    result = evaluate_reward(
        _source(body, arena),
        [real_params()],
        limits=LIMITS,
        python_guards=False,
        disabled_layers=("landlock",),
    )
    assert result.layers["seccomp"].startswith("active (all opens refused")
    (err,) = result.errors
    assert "ModuleNotFoundError" in err.message or "PermissionError" in err.message


def test_threads_allowed_mode_still_refuses_processes(arena: dict) -> None:
    body = (
        "import threading\n    t = threading.Thread(target=lambda: None)\n    t.start()\n"
        "    t.join()\n    os.fork()"
    )
    limits = SandboxLimits(per_call_seconds=1.0, allow_threads=True)
    with host_intact(arena["dir"]):
        result = evaluate_reward(
            _source(body, arena), [real_params()], limits=limits, python_guards=False
        )
    (err,) = result.errors
    assert err.line == 10 and "PermissionError" in err.message  # the os.fork() line


CAPS_SCRIPT = """
import json, sys
from training.sandbox import evaluate_reward, isolation_support, SandboxLimits
status = open('/proc/self/status').read()
cap_eff = [l.split()[1] for l in status.splitlines() if l.startswith('CapEff')][0]
src = sys.argv[1]
result = evaluate_reward(src, [{}], limits=SandboxLimits(per_call_seconds=1.0), python_guards=False)
print(json.dumps({"cap_eff": cap_eff, "layers": result.layers,
                  "errors": [e.message for e in result.errors]}))
"""


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("setpriv"), reason="needs root + setpriv")
def test_a_caller_without_privileges_gets_the_same_layers(arena: dict) -> None:
    """Root with every capability dropped stands in for an ordinary user here: no
    CAP_SYS_ADMIN (namespaces need a user namespace), no CAP_SYS_RESOURCE (RLIMIT_NPROC). It
    keeps CAP_SETFCAP, which an ordinary user does not need: only uid 0 needs it to map itself
    into the user namespace its root is built in (the mount namespace; without it, fail closed)."""
    source = _source(
        "pid = os.fork()\n    if pid == 0:\n        os._exit(0)\n    " + ATTACKS["write"], arena
    )
    cmd = [
        "setpriv",
        "--inh-caps=-all,+setfcap",
        "--ambient-caps=+setfcap",
        "--bounding-set=-all,+setfcap",
        "--securebits=+noroot,+noroot_locked,+no_setuid_fixup,+no_setuid_fixup_locked",
        sys.executable,
        "-c",
        CAPS_SCRIPT,
        source,
    ]
    out = subprocess.run(
        cmd, capture_output=True, text=True, timeout=60, cwd=Path(__file__).resolve().parents[3]
    )
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert int(report["cap_eff"], 16) == 1 << 31  # CAP_SETFCAP alone
    assert report["errors"] and "PermissionError" in report["errors"][0]
    assert not Path(arena["canary"]).exists()
    here = isolation_support()
    for layer in ("rlimits", "no_new_privs", "landlock", "seccomp", "namespaces"):
        assert report["layers"][layer] == here[layer], layer
    # The pids cgroup is root's fallback; without privileges RLIMIT_NPROC does that job.
    assert report["layers"]["cgroup_pids"].startswith("unavailable")
