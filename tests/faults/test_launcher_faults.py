"""`manage.py up`'s plan for faults: one worker per kind of work (a user's jobs cannot starve
the reaper or others), job workers at a lower CPU priority than the web, beat on its own, and an
embedded Redis that keeps its data (queued tasks) across a crash."""

from __future__ import annotations

import os
import signal
import sys
import tempfile
from pathlib import Path

import psutil
import pytest
import redis

from console.launcher import (
    ChildSpec,
    ConsoleOptions,
    EmbeddedRedis,
    Supervisor,
    beat_spec,
    worker_spec,
)


def test_up_runs_one_worker_per_kind_of_work():
    plans = {p.name: p for p in ConsoleOptions(concurrency=2).workers()}
    assert set(plans) == {"quick", "interactive", "training", "evaluation"}
    assert plans["quick"].queues == ("default",)  # the reaper and the league: never queued
    assert plans["interactive"].queues == ("interactive",)  # behind users' validations
    assert plans["interactive"].nice == plans["quick"].nice
    assert 0 < plans["quick"].nice < plans["training"].nice  # web > quick tasks > jobs
    assert plans["training"].queues == ("training",) and plans["training"].concurrency == 2
    assert plans["training"].nice > 0 and plans["evaluation"].nice > 0
    with_sim = {p.name for p in ConsoleOptions(simulation_slots=3).workers()}
    assert "simulation" in with_sim
    spec = worker_spec(plans["training"], {})
    assert spec.name == "worker-training" and "--beat" not in spec.argv
    assert spec.argv[spec.argv.index("-Q") + 1] == "training"
    assert "beat" in beat_spec(ConsoleOptions(), {}).argv


def test_a_child_runs_at_the_niceness_asked_for():
    with Supervisor(stop_timeout=5) as sup:
        argv = [sys.executable, "-c", "import time; time.sleep(30)"]
        child = sup.start(ChildSpec("sleeper", argv, nice=7))
        assert psutil.Process(child.process.pid).nice() == min(19, os.nice(0) + 7)


@pytest.mark.slow
def test_the_embedded_redis_keeps_queued_tasks_across_a_crash():
    with tempfile.TemporaryDirectory(prefix="rc-aof-") as folder:
        embedded = EmbeddedRedis(Path(folder) / "redis.sock")
        for attempt in range(2):
            with Supervisor(stop_timeout=5) as sup:
                child = sup.start(embedded.spec())
                sup.wait_until(embedded.ping, what="embedded Redis", timeout=30)
                client = redis.Redis(unix_socket_path=str(embedded.socket_path))
                if attempt == 0:
                    client.rpush("training", b"a queued task")
                    client.execute_command("BGREWRITEAOF")  # on disk now, not in a second
                    sup.wait_until(
                        lambda c=client: c.info("persistence")["aof_rewrite_in_progress"] == 0
                        and any(Path(folder).glob("appendonly*")),
                        what="the append-only file", timeout=30,
                    )  # fmt: skip
                    os.kill(child.process.pid, signal.SIGKILL)  # a crash, not a clean stop
                    child.process.wait()
                else:
                    assert client.lrange("training", 0, -1) == [b"a queued task"]
                client.close()
