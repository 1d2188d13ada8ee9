"""A task goes through Redis to a real `celery -A console worker` process and back."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator

import pytest

from console.celery import QUEUE_DEFAULT, QUEUES, TASK_ROUTES
from console.celery import app as celery_app
from console.tasks import ping
from tests.support import ChildProcess, celery_worker_process


@pytest.fixture(scope="module")
def celery_worker(
    redis_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ChildProcess]:
    """A worker on the default queue only, on the tests' Redis and key prefix."""
    with celery_worker_process(
        queues=[QUEUE_DEFAULT],
        env={**os.environ, **redis_env},
        log_path=tmp_path_factory.mktemp("worker") / "worker.log",
        pool="solo",
    ) as worker:
        yield worker


def test_ping_round_trip_through_a_worker(celery_worker: ChildProcess) -> None:
    message = f"hello-{uuid.uuid4().hex}"
    result = ping.delay(message)
    assert result.get(timeout=60) == message
    assert result.successful()
    assert celery_worker.popen.poll() is None


def test_tasks_route_to_their_queues() -> None:
    router = celery_app.amqp.router
    assert set(QUEUES) == {"training", "simulation", "evaluation", "interactive", "default",
                           "readiness"}  # fmt: skip
    assert celery_app.conf.task_routes == TASK_ROUTES
    cases = {
        "training.tasks.train_model": "training",
        "training.tasks.simulate_episodes": "simulation",
        "training.tasks.rollout_worker": "simulation",
        "leaderboard.tasks.evaluate_submission": "evaluation",
        "training.tasks.evaluate_race": "evaluation",  # head-to-head races
        "training.tasks.check_readiness": "readiness",
        "console.tasks.ping": "default",
        # What a page waits for has its own queue: never behind the reaper, nor it behind them.
        "training.tasks.validate_reward": "interactive",
        "training.tasks.replay_reward": "interactive",
        "training.tasks.import_model": "interactive",
        "training.tasks.export_car_model": "interactive",
        "training.tasks.reap_orphans": "default",
        "training.tasks.prune_uploads": "default",
    }
    for name, queue in cases.items():
        route = router.route({}, name)
        assert route["queue"].name == queue, name
