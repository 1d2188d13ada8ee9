"""The parent's clock decides: a child that forges or stops its heartbeat is still killed at
the deadline with its whole process group, and no child outlives its caller.

Python guards are off in these tests so the reward can reach its own heartbeat (through gc),
which is the worst case: the guards normally refuse both ``gc`` and private attributes.
"""

from __future__ import annotations

import subprocess
import sys
import time

import psutil
import pytest

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.sandbox import SandboxLimits, SandboxProcess, SandboxTimeout, evaluate_reward
from training.sandbox.oneshot import SERVE_TARGET

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
