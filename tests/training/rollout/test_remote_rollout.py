"""Rollouts on another machine: a real Celery worker on the ``simulation`` queue serves a
sandboxed rollout through real Redis, and gives exactly what a local sandboxed worker gives."""

from __future__ import annotations

import functools
from collections.abc import Iterator

import numpy as np
import pytest

from tests.support import ChildProcess, celery_worker_process
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import RolloutError, SandboxedVecEnv

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


def run(venv, steps: int = 40):
    venv.seed(5)
    frames = [venv.reset()]
    rewards, statuses = [], []
    rng = np.random.default_rng(0)
    for _ in range(steps):
        obs, reward, _, infos = venv.step(rng.integers(0, venv.action_space.n, venv.num_envs))
        frames.append(obs)
        rewards.append(reward)
        statuses.append([i["status"] for i in infos])
    venv.close()
    if isinstance(frames[0], dict):  # camera + LIDAR: one stack per sensor
        return {k: np.stack([f[k] for f in frames]) for k in frames[0]}, np.stack(rewards), statuses
    return np.stack(frames), np.stack(rewards), statuses


def same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    return np.array_equal(a, b)


BOXES_AND_LIDAR = EnvSpec(
    track="racecraft_oval",
    sensors=("FRONT_FACING_CAMERA", "LIDAR"),
    race={"race_type": "OBJECT_AVOIDANCE", "number_of_objects": 3, "randomize_objects": True},
)


@pytest.mark.parametrize(
    "spec", [EnvSpec(track="racecraft_summit"), BOXES_AND_LIDAR], ids=["time-trial", "boxes-lidar"]
)
def test_remote_rollout_matches_a_local_one(simulation_worker, redis_url, settings, spec):
    from training import dispatch
    from training.rollout.remote import RemoteVecEnv

    launch_simulation_worker = functools.partial(dispatch.send, dispatch.SIMULATE_ROLLOUT)
    remote = RemoteVecEnv(spec, 4, REWARD, launch=launch_simulation_worker, num_slots=2,
                          redis_url=redis_url, prefix=settings.REDIS_PREFIX)  # fmt: skip
    assert remote.sizes == [2, 2]
    local = SandboxedVecEnv(spec, 4, REWARD, num_workers=2)
    rf, rr, rs = run(remote)
    lf, lr, ls = run(local)
    assert same(rf, lf)
    assert np.array_equal(rr, lr)
    assert rs == ls
    assert rr.max() > 0.01  # the stateful reward paid for progress, per car


def test_no_simulation_worker_is_a_clear_error(redis_url, settings, monkeypatch):
    from training.rollout import remote

    monkeypatch.setattr(remote, "START_TIMEOUT_S", 2.0)
    launched = []
    with pytest.raises(RolloutError, match="no simulation worker took the rollout"):
        remote.RemoteVecEnv(EnvSpec(track="racecraft_oval"), 2, REWARD,
                            launch=lambda **kwargs: launched.append(kwargs), num_slots=1,
                            redis_url=redis_url, prefix=settings.REDIS_PREFIX)  # fmt: skip
    assert [k["slot"] for k in launched] == [0]  # the job's launcher was asked for one worker


@pytest.mark.slow
def test_streamed_training_on_celery_simulation_workers(simulation_worker, redis_url, settings):
    from training import dispatch
    from training.rl.hyperparams import parse_hyperparameters
    from training.rl.runner import TrainingConfig, TrainingHooks
    from training.rl.streamed import train
    from training.rollout.backends import StreamRollouts
    from training.worker.common import SIMULATE_EPISODES

    class Two(TrainingHooks):
        def __init__(self) -> None:
            self.results = []

        def on_iteration(self, result, checkpoint, rows) -> None:
            self.results.append(result)

        def should_stop(self) -> bool:
            return len(self.results) >= 2

    launch = functools.partial(dispatch.send, SIMULATE_EPISODES)
    backend = StreamRollouts(redis_url=redis_url, workers=2, prefix=settings.REDIS_PREFIX,
                             launch=launch)  # fmt: skip
    hooks = Two()
    summary = train(TrainingConfig(
        spec=EnvSpec(track="racecraft_oval",
                     action_space=[{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]),
        hyperparameters=parse_hyperparameters({"num_episodes_between_training": 4}),
        max_minutes=60, reward_source=REWARD, eval_episodes=2, rollouts=backend,
    ), hooks)  # fmt: skip
    assert summary.iterations >= 2 and all(r.episodes == 4 for r in hooks.results)
    assert hooks.results[1].total_steps > hooks.results[0].total_steps
