"""The parent's clock decides: a child that forges or stops its heartbeat is still killed at
the deadline with its whole process group, and no child outlives its caller. A call's clock
leaves out the time its process waited for a CPU (a machine busy with other jobs), up to a
backstop on the wall clock.

Python guards are off in these tests so the reward can reach its own heartbeat (through gc),
which is the worst case: the guards normally refuse both ``gc`` and private attributes.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import psutil
import pytest

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.sandbox import SandboxLimits, SandboxProcess, SandboxTimeout, evaluate_reward
from training.sandbox.oneshot import SERVE_TARGET
from training.sandbox.process import CALL_BACKSTOP, call_overran, calling_pid, runqueue_wait_s

LIMITS = SandboxLimits(per_call_seconds=0.5, cpu_seconds=120)
FIND_HEARTBEAT = (
    "import gc, time\n\n"
    "def heartbeat():\n"
    "    for o in gc.get_objects():\n"
    "        if type(o).__name__ == 'RewardCallable':\n"
    "            return o._hb\n\n"
)


def _gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def _wait_gone(pid: int, seconds: float = 30.0) -> bool:
    deadline = time.monotonic() + seconds
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return _gone(pid)


def test_a_call_that_stops_its_heartbeat_and_sleeps_is_killed() -> None:
    source = FIND_HEARTBEAT + (
        "def reward_function(params):\n"
        "    heartbeat()[1] = 0  # 'no call under way'\n"
        "    time.sleep(3600)\n"
    )
    with host_intact():  # the child and anything it started are gone afterwards
        result = evaluate_reward(source, [real_params()], limits=LIMITS, python_guards=False)
    (error,) = result.errors
    assert "took longer than 0.5 s per call" in error.message


def test_a_call_that_forges_progress_is_killed() -> None:
    source = FIND_HEARTBEAT + (
        "def reward_function(params):\n"
        "    hb = heartbeat()\n"
        "    while True:  # a new 'call' every millisecond\n"
        "        hb[0] += 1\n        hb[1] = time.monotonic_ns()\n        time.sleep(0.001)\n"
    )
    with host_intact():
        result = evaluate_reward(source, [real_params()], limits=LIMITS, python_guards=False)
    (error,) = result.errors
    assert "took longer than 0.5 s per call" in error.message


def test_the_overall_deadline_ends_a_validation() -> None:
    source = "import time\n\ndef reward_function(params):\n    time.sleep(0.3)\n    return 1.0\n"
    with host_intact():
        result = evaluate_reward(
            source, [real_params()] * 50, limits=LIMITS, deadline_seconds=3.0, python_guards=False
        )
    values = [o.value for o in result.outcomes]
    assert values[0] == 1.0 and values[-1] is None
    assert any("overall limit of 3 s" in e.message for e in result.errors)


def test_the_overall_deadline_kills_an_idle_child() -> None:
    source = "def reward_function(params):\n    return 1.0\n"
    with host_intact():
        sb = SandboxProcess(
            target=SERVE_TARGET, reward_source=source, limits=LIMITS, deadline_seconds=2.0
        )
        with pytest.raises(SandboxTimeout, match="overall limit of 2 s"):
            sb.start()  # a loaded machine may spend the 2 s starting it: killed the same way
            sb.recv()  # no timeout of ours: only the overall deadline ends the wait
        pid = sb.pid
        sb.close()
    assert pid is not None and _gone(pid)


CALLER = """
import sys, time
from training.sandbox import SandboxProcess, SandboxLimits
from training.sandbox.oneshot import SERVE_TARGET
source = '''import ctypes
RC = ctypes.CDLL(None, use_errno=True).prctl(1, 0, 0, 0, 0)  # PR_SET_PDEATHSIG: none

def reward_function(params):
    return float(RC)
'''
sb = SandboxProcess(target=SERVE_TARGET, reward_source=source, python_guards=False,
                    limits=SandboxLimits(per_call_seconds=5.0))
sb.start()
sb.send({})
print(sb.pid, sb.recv(10).value, flush=True)
time.sleep(600)
"""


@pytest.mark.slow
def test_a_child_that_clears_its_parent_death_signal_still_dies_with_its_caller() -> None:
    caller = subprocess.Popen([sys.executable, "-c", CALLER], stdout=subprocess.PIPE, text=True)
    try:
        assert caller.stdout is not None
        pid_text, rc_text = caller.stdout.readline().split()
        child = int(pid_text)
        assert float(rc_text) == -1.0  # prctl refused by seccomp
        assert not _gone(child)
    finally:
        caller.kill()
        caller.wait()
    assert _wait_gone(child)


def test_the_time_a_call_waited_for_a_cpu_is_not_the_users() -> None:
    assert not call_overran(wall_s=3.0, waited_s=2.5, limit_s=1.0)  # ran or slept 0.5 s
    assert call_overran(wall_s=3.0, waited_s=1.5, limit_s=1.0)  # ran or slept 1.5 s
    assert call_overran(wall_s=1.5, waited_s=0.0, limit_s=1.0)  # a sleep counts in full
    # However long it waited, the wall clock ends it at the backstop.
    assert call_overran(wall_s=CALL_BACKSTOP + 0.1, waited_s=CALL_BACKSTOP, limit_s=1.0)


def test_the_kernel_says_how_long_a_process_waited_for_a_cpu() -> None:
    waited = runqueue_wait_s(os.getpid())
    assert waited is not None and waited >= 0.0
    assert runqueue_wait_s(2**22 + 1) is None  # above pid_max: no such process


BURN_CPU = (
    "import time\n\n"
    "def reward_function(params):\n"
    "    end = time.process_time() + 0.2  # 0.2 s of the CPU, a fifth of the limit\n"
    "    while time.process_time() < end:\n"
    "        pass\n"
    "    return 1.0\n"
)
HOG = "import os, sys\nos.sched_setaffinity(0, {int(sys.argv[1])})\nwhile True:\n    pass\n"


def test_a_call_that_waits_for_a_busy_cpu_is_not_killed_for_it() -> None:
    """Seven busy processes (each its own session, as other jobs are) share one CPU with the
    sandbox: its 0.2 s of work takes longer than the 1 s limit on the wall clock, and the call
    still returns, since the kernel counts the time it waited for its turn."""
    cpu = min(os.sched_getaffinity(0))
    limits = SandboxLimits(per_call_seconds=1.0, cpu_seconds=120)
    with host_intact():
        sb = SandboxProcess(
            target=SERVE_TARGET, reward_source=BURN_CPU, limits=limits, python_guards=False
        )
        hogs: list[subprocess.Popen] = []
        try:
            sb.start()
            caller = calling_pid(sb.pid)
            if sb.layers.get("namespaces") == "active":  # the calls run in the forked process
                assert caller != sb.pid and psutil.Process(caller).ppid() == sb.pid
            os.sched_setaffinity(caller, {cpu})
            hogs = [
                subprocess.Popen([sys.executable, "-c", HOG, str(cpu)], start_new_session=True)
                for _ in range(7)
            ]
            waited, started = runqueue_wait_s(caller), time.monotonic()
            sb.send(real_params())
            value = sb.recv(CALL_BACKSTOP * 6).value
            wall = time.monotonic() - started
            queued = runqueue_wait_s(caller)
        finally:
            for hog in hogs:
                hog.kill()
                hog.wait()
            sb.close()
    assert value == 1.0
    assert wall > limits.per_call_seconds  # the wall clock alone would have killed it
    assert waited is not None and queued is not None and queued - waited > 0.5
