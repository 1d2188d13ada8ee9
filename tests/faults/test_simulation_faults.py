"""Streamed training under faults (issue 14), through the tests' real Redis: a simulation
worker process killed with SIGKILL mid-iteration costs no iteration and no episode is counted
twice; a trainer killed with SIGKILL resumes from its last checkpoint. Every wait is on a
condition with a generous deadline."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from training.rl.hyperparams import parse_hyperparameters
from training.rl.runner import TrainingConfig, TrainingHooks, TrainingLoop, train
from training.rl.simulation import launch_local
from training.rollout.backends import StreamRollouts
from training.rollout.envs import EnvSpec
from training.rollout.streamed import StreamedExperience

pytestmark = pytest.mark.slow
ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 2.0)]
REWARD = "def reward_function(params):\n    return 1.0 if params['all_wheels_on_track'] else 1e-3\n"
QUOTA = 4


def _config(redis_url: str, prefix: str, **overrides) -> TrainingConfig:
    values = {
        "spec": EnvSpec(track="racecraft_oval", action_space=ACTIONS),
        "hyperparameters": parse_hyperparameters(
            {"num_episodes_between_training": QUOTA, "num_epochs": 3, "batch_size": 32}
        ),
        "max_minutes": 60,
        "reward_source": REWARD,
        "eval_episodes": 2,
        "rollouts": StreamRollouts(
            redis_url=redis_url, workers=2, launch=launch_local, prefix=prefix
        ),
    }
    values.update(overrides)
    return TrainingConfig(**values)


class KillOneWorker(TrainingHooks):
    """Kills slot 0's worker process when the second iteration's first episode is counted."""

    def __init__(self, iterations: int) -> None:
        self.iterations = iterations
        self.source: StreamedExperience | None = None
        self.results = []
        self.killed: int | None = None

    def on_episode(self, entry: dict) -> None:
        source = self.source
        if self.killed is None and source is not None and source.episodes_total == QUOTA + 1:
            process = source.slots[0].process
            self.killed = process.pid
            os.kill(process.pid, signal.SIGKILL)

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)

    def should_stop(self) -> bool:
        return len(self.results) >= self.iterations


def test_a_simulation_worker_killed_mid_iteration_costs_no_iteration(redis_url, settings):
    hooks = KillOneWorker(iterations=3)
    loop = TrainingLoop(_config(redis_url, settings.REDIS_PREFIX), hooks)
    assert isinstance(loop.source, StreamedExperience)
    hooks.source = source = loop.source
    summary = loop.run()
    assert hooks.killed is not None
    n = summary.iterations
    assert n >= 3 and [r.iteration for r in hooks.results] == list(range(1, n + 1))
    assert all(r.episodes == QUOTA for r in hooks.results)  # no iteration short or lost
    tickets = source.counted_tickets
    assert len(tickets) == len(set(tickets))  # no episode counted twice
    for version in range(n):
        assert sum(t.startswith(f"{version}:") for t in tickets) == QUOTA
    assert source.deaths == 1 and source.slots[0].restarts == 1  # noticed, and started again


TRAINER = """
import json, sys
from pathlib import Path
from tests.faults.test_simulation_faults import _config
from training.rl.runner import TrainingHooks, train

class Save(TrainingHooks):
    def on_iteration(self, result, checkpoint, rows):
        out = Path(sys.argv[3])
        (out / "last.zip").write_bytes(checkpoint)
        (out / "last.json").write_text(json.dumps({"total_steps": result.total_steps}))

train(_config(sys.argv[1], sys.argv[2]), Save())
"""


def test_a_trainer_killed_resumes_from_its_last_checkpoint(redis_url, settings, tmp_path):
    root = Path(__file__).resolve().parents[2]
    trainer = subprocess.Popen([sys.executable, "-c", TRAINER, redis_url, settings.REDIS_PREFIX,
                                str(tmp_path)], cwd=root)  # fmt: skip
    try:
        deadline = time.monotonic() + 600
        while not (tmp_path / "last.json").exists():
            assert trainer.poll() is None, "the trainer ended before its first checkpoint"
            assert time.monotonic() < deadline, "no checkpoint within 600 s"
            time.sleep(0.5)  # last.json is written after last.zip
    finally:
        trainer.send_signal(signal.SIGKILL)
        trainer.wait(timeout=30)
    saved = json.loads((tmp_path / "last.json").read_text())

    class One(TrainingHooks):
        def __init__(self) -> None:
            self.results = []

        def on_iteration(self, result, checkpoint, rows) -> None:
            self.results.append(result)

        def should_stop(self) -> bool:
            return bool(self.results)

    hooks = One()
    config = _config(redis_url, settings.REDIS_PREFIX,
                     initial_checkpoint=(tmp_path / "last.zip").read_bytes())  # fmt: skip
    summary = train(config, hooks)
    assert summary.iterations >= 1 and hooks.results[0].iteration == 1
    assert hooks.results[0].total_steps > saved["total_steps"]  # went on from the checkpoint
