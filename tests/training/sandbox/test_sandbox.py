"""The sandbox's API: starting, messages, limits, the guard, the protocol, dying children."""

from __future__ import annotations

import math
import os
import resource
import signal
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.sandbox import (
    RewardFunctionError,
    SandboxCrashed,
    SandboxedReward,
    SandboxLimits,
    SandboxProcess,
    SandboxTimeout,
    evaluate_reward,
    isolation_support,
    landlock,
    lockdown,
    run_sandboxed,
    seccomp,
)
from training.sandbox.guard import RewardCallable, load_reward_function
from training.sandbox.oneshot import EVALUATE_TARGET, SERVE_TARGET
from training.sandbox.protocol import ProtocolError, decode, encode

CENTER = """
def reward_function(params):
    w = params["track_width"]
    d = params["distance_from_center"]
    return 1.0 if d <= 0.1 * w else 0.5 if d <= 0.25 * w else 1e-3
"""
FAST = SandboxLimits(per_call_seconds=0.5, cpu_seconds=30)


def test_isolation_layers_are_reported() -> None:
    layers = isolation_support()
    expected = {
        "environment",
        "file_descriptors",
        "namespaces",
        "rlimits",
        "no_new_privs",
        "landlock",
        "seccomp",
        "python_guards",
    }
    assert expected <= set(layers)
    for name, state in layers.items():
        assert state.startswith(("active", "unavailable")), (name, state)
    assert layers["environment"] == layers["rlimits"] == layers["no_new_privs"] == "active"
    if landlock.abi_version() > 0:
        assert layers["landlock"] == "active"
    if seccomp.supported():
        assert layers["seccomp"].startswith("active")


def test_evaluate_returns_rewards_and_output() -> None:
    source = CENTER.replace("    w =", "    print('seen', params['steps'])\n    w =")
    params = real_params()
    with host_intact():
        result = evaluate_reward(source, [params, params], limits=FAST)
    assert [o.value for o in result.outcomes] == [1.0, 1.0] or all(
        o.value is not None for o in result.outcomes
    )
    assert result.errors == []
    assert result.output.count("seen") == 2


def test_an_error_in_one_call_does_not_stop_the_others() -> None:
    source = "def reward_function(params):\n    return 1.0 / params['speed']\n"
    good, bad = real_params(), dict(real_params(), speed=0.0)
    result = evaluate_reward(source, [good, bad, good], limits=FAST)
    assert result.outcomes[0].value is not None and result.outcomes[2].value is not None
    err = result.outcomes[1].error
    assert err is not None and err.type == "TEST_FAILURE" and err.line == 2
    assert "ZeroDivisionError at step 2" in err.message


def test_a_call_that_hangs_is_killed_and_the_rest_still_run() -> None:
    source = "def reward_function(params):\n    while params['speed'] == 0:\n        pass\n    return 2.0\n"  # noqa: E501
    good, bad = real_params(), dict(real_params(), speed=0)
    start = time.monotonic()
    with host_intact():
        result = evaluate_reward(source, [good, bad, good], limits=FAST)
    assert time.monotonic() - start < 5
    assert [o.value for o in result.outcomes] == [2.0, None, 2.0]
    assert "took longer than 0.5 s per call" in result.outcomes[1].error.message


def test_module_errors_come_back_once_per_call_with_the_line() -> None:
    result = evaluate_reward(
        "x = 1\ny = undefined_name\n\ndef reward_function(p):\n    return 1\n",
        [real_params()],
        limits=FAST,
    )
    (err,) = result.errors
    assert err.type == "TEST_FAILURE" and err.line == 2 and "NameError" in err.message


def test_serve_target_answers_each_call_and_reports_the_step() -> None:
    with host_intact(), SandboxedReward(CENTER, FAST) as reward:
        params = real_params()
        assert reward(params) in (1.0, 0.5, 1e-3)
        assert reward(params) in (1.0, 0.5, 1e-3)
    source = (
        "def reward_function(params):\n    return float('nan') if params['steps'] > 1 else 1.0\n"
    )
    with SandboxedReward(source, FAST) as reward:
        assert reward(dict(real_params(), steps=1)) == 1.0
        with pytest.raises(RewardFunctionError) as info:
            reward(dict(real_params(), steps=2))
    assert info.value.step == 2
    assert "returned nan at step 2" in info.value.error.message


def test_run_sandboxed_passes_messages_and_returns_the_result() -> None:
    got: list = []
    value = run_sandboxed(
        target=EVALUATE_TARGET,
        reward_source=CENTER,
        args={"params": [real_params()] * 3},
        limits=FAST,
        on_message=got.append,
    )
    assert value == {}
    assert [m["i"] for m in got] == [0, 1, 2]


def test_send_and_recv_with_a_long_lived_target() -> None:
    with (
        host_intact(),
        SandboxProcess(target=SERVE_TARGET, reward_source=CENTER, limits=FAST) as sb,
    ):
        for _ in range(3):
            sb.send(real_params())
            assert sb.recv(5).kind == "message"
        sb.close(grace_seconds=2)  # EOF: the target returns its call count
    assert sb._proc is not None and sb._proc.returncode == 0


def test_a_child_killed_from_outside_is_reported_in_plain_words() -> None:
    with host_intact():
        sb = SandboxProcess(target=SERVE_TARGET, reward_source=CENTER, limits=FAST)
        sb.start()
        os.kill(sb.pid, signal.SIGKILL)
        with pytest.raises(SandboxCrashed, match="sandbox was stopped: was killed"):
            sb.recv(5)
        sb.close()


def test_no_answer_before_the_deadline_is_a_timeout() -> None:
    source = "def reward_function(params):\n    return 1.0\n"
    with host_intact():
        sb = SandboxProcess(target=SERVE_TARGET, reward_source=source, limits=FAST)
        sb.start()
        with pytest.raises(SandboxTimeout, match="no answer within 0.2 s"):
            sb.recv(0.2)  # nothing was sent: the target waits forever
        sb.close()


def test_the_memory_limit_holds_in_numpy() -> None:
    source = "import numpy as np\n\ndef reward_function(params):\n    return float(np.ones(1 << 28).sum())\n"  # noqa: E501
    small = SandboxLimits(per_call_seconds=2, memory_bytes=256 << 20)
    (err,) = evaluate_reward(source, [real_params()], limits=small).errors
    assert "MemoryError" in err.message or "Unable to allocate" in err.message


@pytest.mark.slow
def test_the_cpu_limit_kills_a_child_that_hides_from_the_watchdog() -> None:
    # Python guards off: the code zeroes its own heartbeat; RLIMIT_CPU or the parent's own
    # deadlines stop it, whichever comes first. As the first process of its PID namespace the
    # child is spared the soft limit's SIGXCPU, so the hard limit's SIGKILL ends it: its
    # waiter outside the namespace must pass that on (it said "exited unexpectedly (status
    # 3)" before).
    source = (
        "import gc\n\ndef reward_function(params):\n"
        "    for o in gc.get_objects():\n"
        "        if type(o).__name__ == 'RewardCallable':\n"
        "            o._hb[1] = 0; o._hb = memoryview(bytearray(16)).cast('q')\n"
        "    while True:\n        pass\n"
    )
    limits = SandboxLimits(per_call_seconds=0.5, cpu_seconds=2)
    start = time.monotonic()
    result = evaluate_reward(source, [real_params()], limits=limits, python_guards=False)
    (err,) = result.errors
    words = ("CPU", "SIGKILL", "took longer than 0.5 s", "ran past its overall limit")
    assert any(w in err.message for w in words), err.message
    assert time.monotonic() - start < 10


@pytest.mark.parametrize("death", ["SIGKILL", "SIGTERM", "SIGXCPU", "exit 7"])
def test_the_waiter_outside_the_pid_namespace_ends_as_the_sandboxed_process_did(
    death: str,
) -> None:
    """``_wait_and_exit`` passes on how the sandboxed process ended, a SIGKILL included (the
    parent's words for the user come from it): here in a forked process, where a Python
    exception would end it with status 3."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - runs in the forked process
        try:
            inner = os.fork()
            if inner == 0:
                resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
                if death.startswith("exit"):
                    os._exit(int(death.split()[1]))
                sig = signal.Signals[death]
                if sig is not signal.SIGKILL:
                    signal.signal(sig, signal.SIG_DFL)
                os.kill(os.getpid(), sig)
                os._exit(0)
            lockdown._wait_and_exit(inner)
        finally:
            os._exit(3)
    _, status = os.waitpid(pid, 0)
    if death.startswith("exit"):
        assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == int(death.split()[1])
    else:
        assert os.WIFSIGNALED(status), f"exit status {os.waitstatus_to_exitcode(status)}"
        assert os.WTERMSIG(status) == signal.Signals[death]


def test_the_parent_keeps_running_when_many_sandboxes_die() -> None:
    source = "def reward_function(params):\n    return 1.0\n"
    with host_intact():
        for _ in range(3):
            sb = SandboxProcess(target=SERVE_TARGET, reward_source=source, limits=FAST)
            sb.start()
            sb._kill("test")
            with pytest.raises(SandboxCrashed):
                sb.recv(5)
            sb.close()


@pytest.mark.slow
def test_the_child_dies_with_its_parent() -> None:
    script = (
        "import sys, time\n"
        "from training.sandbox import SandboxProcess\n"
        "from training.sandbox.oneshot import SERVE_TARGET\n"
        "sb = SandboxProcess(target=SERVE_TARGET, reward_source='def reward_function(p):\\n return 1\\n')\n"  # noqa: E501
        "sb.start(); print(sb.pid, flush=True); time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    assert psutil.pid_exists(child_pid)
    # The waiter outside the PID namespace, and the sandboxed process it forked into it.
    sandboxed = [child_pid] + [p.pid for p in psutil.Process(child_pid).children()]
    assert len(sandboxed) == 2
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 10
    while [pid for pid in sandboxed if _running(pid)] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in sandboxed if _running(pid)]
    # The next sandboxes sweep the cgroups the killed parent could not remove.
    from training.sandbox.cgroup import ROOT

    def left() -> list:
        found = []
        for controller in ("pids", "memory"):
            if (ROOT / controller).exists():
                found += list((ROOT / controller).rglob(f"racecraft-sandbox-{child_pid}"))
        return found

    for _ in range(5):  # a process the kernel is still tearing down keeps its cgroup busy
        isolation_support()
        if not left():
            break
        time.sleep(0.5)
    assert not left()


def _running(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


# --- the in-child guard, exercised in-process ------------------------------------------------


def _guarded(source: str) -> RewardCallable:
    hb = memoryview(bytearray(32)).cast("q")
    return RewardCallable(load_reward_function(source), hb)


def test_mutating_params_cannot_break_the_caller() -> None:
    source = (
        "def reward_function(params):\n"
        "    params['waypoints'].clear()\n    params['closest_waypoints'][0] = 'x'\n"
        "    params['x'] = None\n    params.clear()\n    return 1.0\n"
    )
    reward = _guarded(source)
    params = real_params()
    params["closest_waypoints"] = list(params["closest_waypoints"])
    snapshot = {k: (list(v) if isinstance(v, list) else v) for k, v in params.items()}
    for _ in range(3):
        assert reward(params) == 1.0
    assert params == snapshot


@pytest.mark.parametrize(
    ("returned", "shown"),
    [
        ("float('nan')", "nan"),
        ("float('inf')", "inf"),
        ("-1e5 - 1", "-100001"),
        ("'0.5'", "'0.5'"),
        ("None", "None"),
        ("10 ** 400", "1000000000"),
        ("np.float64('nan')", "nan"),
    ],
)
def test_bad_return_values_name_the_value_and_step(returned: str, shown: str) -> None:
    reward = _guarded(
        f"import numpy as np\n\ndef reward_function(params):\n    return {returned}\n"
    )
    with pytest.raises(RewardFunctionError) as info:
        reward(real_params())
    assert f"returned {shown}" in info.value.error.message.replace("np.float64(nan)", "nan")
    assert "at step 1" in info.value.error.message


@pytest.mark.parametrize("value", ["1", "2.5", "np.float32(0.25)", "np.int64(3)", "True", "-1e5"])
def test_numbers_are_accepted_as_floats(value: str) -> None:
    reward = _guarded(f"import numpy as np\n\ndef reward_function(params):\n    return {value}\n")
    result = reward(real_params())
    assert type(result) is float and math.isfinite(result)


# --- the wire format -------------------------------------------------------------------------


def test_protocol_round_trips_arrays_and_refuses_garbage() -> None:
    msg = {"obs": np.arange(6, dtype=np.float32).reshape(2, 3), "r": [1.0, float("nan")], "s": "x"}
    frame = encode(msg)
    back = decode(frame[4:])
    assert np.array_equal(back["obs"], msg["obs"]) and back["obs"].dtype == np.float32
    assert back["s"] == "x" and math.isnan(back["r"][1])
    with pytest.raises(TypeError):
        encode({"bad": np.array([object()])})
    for garbage in (b"", b"\x00\x00\x00\x05{oops", b"\xff" * 64, frame[4:-1]):
        with pytest.raises(ProtocolError):
            decode(garbage)
    evil = encode({"a": np.zeros(2)})[4:].replace(b'"float64"', b'"object0"')
    with pytest.raises(ProtocolError):
        decode(evil)
