"""Simulation workers on another machine: real Celery workers on the ``simulation`` queue drive
a streamed training run through real Redis."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.support import ChildProcess, celery_worker_process
from training.rl.hyperparams import parse_hyperparameters
from training.rl.runner import TrainingConfig, TrainingHooks, train
from training.rollout.backends import StreamRollouts
from training.rollout.envs import EnvSpec

REWARD = """
state = {"last": None}

def reward_function(params):
    last, state["last"] = state["last"], params["progress"]
    gained = 0.0 if last is None or params["steps"] <= 1 else params["progress"] - last
    return max(gained, 0.0) + 1e-3
"""
pytestmark = pytest.mark.slow


@pytest.fixture
def simulation_worker(child_env, tmp_path) -> Iterator[ChildProcess]:
    with celery_worker_process(
        queues=["simulation"], env=child_env, log_path=tmp_path / "sim.log", concurrency=2
    ) as worker:
        yield worker


class Two(TrainingHooks):
    def __init__(self) -> None:
        self.results = []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)

    def should_stop(self) -> bool:
        return len(self.results) >= 2


def test_streamed_training_on_celery_simulation_workers(simulation_worker, redis_url, settings):
    from training.worker.common import send_simulation

    # The console's own launch: the worker uses its own Redis settings, not the message's.
    backend = StreamRollouts(redis_url=redis_url, workers=2, prefix=settings.REDIS_PREFIX,
                             launch=send_simulation)  # fmt: skip
    hooks = Two()
    summary = train(TrainingConfig(
        spec=EnvSpec(track="racecraft_oval",
                     action_space=[{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]),
        hyperparameters=parse_hyperparameters({"num_episodes_between_training": 4}),
        max_minutes=60, reward_source=REWARD, eval_episodes=2, rollouts=backend,
    ), hooks)  # fmt: skip
    assert summary.iterations >= 2 and all(r.episodes == 4 for r in hooks.results)
    assert hooks.results[1].total_steps > hooks.results[0].total_steps
    assert all(len(r.evaluation.progress) <= 2 for r in hooks.results)
