"""A job worker's process loads torch's optimizer machinery when it starts, so that a user's
first job does not wait for it; the other workers' processes do not."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import pytest

from training import tasks


def consuming(names):
    """Celery's app as a worker's process sees it: the queues its worker consumes."""
    queues = SimpleNamespace(consume_from={name: object() for name in names})
    return SimpleNamespace(amqp=SimpleNamespace(queues=queues))


@pytest.fixture
def warmed(monkeypatch):
    calls = []
    monkeypatch.setattr(tasks, "warm_up", lambda: calls.append(True))
    return calls


@pytest.mark.parametrize("queues", [["training"], ["evaluation"], ["simulation"],
                                    ["default", "training"]])  # fmt: skip
def test_a_job_workers_process_warms_up(monkeypatch, warmed, queues):
    monkeypatch.setattr(tasks, "current_app", consuming(queues))
    tasks._warm_up_job_process()
    assert warmed == [True]


@pytest.mark.parametrize("queues", [["default"], ["interactive"], []])
def test_other_workers_processes_do_not(monkeypatch, warmed, queues):
    monkeypatch.setattr(tasks, "current_app", consuming(queues))
    tasks._warm_up_job_process()
    assert warmed == []


def test_warm_up_loads_what_the_first_optimizer_would():
    """In a fresh process: torch._dynamo is not loaded by torch itself, and is after warm_up
    (the first optimizer of a process imports it)."""
    code = (
        "import sys\n"
        "from training.rl.algorithms import warm_up\n"
        "before = 'torch._dynamo' in sys.modules\n"
        "warm_up()\n"
        "print(before, 'torch._dynamo' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)  # fmt: skip
    assert out.stdout.split() == ["False", "True"]
