"""A task goes through Redis to a real `celery -A console worker` process and back."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from console.celery import QUEUE_DEFAULT, QUEUES, TASK_ROUTES
from console.celery import app as celery_app
from console.tasks import ping

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def celery_worker(redis_env: dict[str, str]) -> Iterator[subprocess.Popen[bytes]]:
    """A worker on the default queue, on the tests' Redis and key prefix."""
    env = {**os.environ, **redis_env}
    worker = subprocess.Popen(
        [sys.executable, "-m", "celery", "-A", "console", "worker", "--loglevel", "WARNING",
         "-Q", QUEUE_DEFAULT, "--pool", "solo", "--without-gossip", "--without-mingle",
         "--hostname", f"test-{uuid.uuid4().hex[:8]}@%h"],
        cwd=REPO,
        env=env,
    )  # fmt: skip
    yield worker
    worker.terminate()
    try:
        worker.wait(30)
    except subprocess.TimeoutExpired:
        worker.kill()
        worker.wait()


def test_ping_round_trip_through_a_worker(celery_worker: subprocess.Popen[bytes]) -> None:
    message = f"hello-{uuid.uuid4().hex}"
    result = ping.delay(message)
    assert result.get(timeout=60) == message
    assert result.successful()
    assert celery_worker.poll() is None


def test_tasks_route_to_the_four_queues() -> None:
    router = celery_app.amqp.router
    assert set(QUEUES) == {"training", "simulation", "evaluation", "default"}
    assert celery_app.conf.task_routes == TASK_ROUTES
    cases = {
        "training.tasks.train_model": "training",
        "training.tasks.simulate_episodes": "simulation",
        "training.tasks.rollout_worker": "simulation",
        "leaderboard.tasks.evaluate_submission": "evaluation",
        "console.tasks.ping": "default",
    }
    for name, queue in cases.items():
        route = router.route({}, name)
        assert route["queue"].name == queue, name
