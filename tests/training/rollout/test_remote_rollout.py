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
        obs, reward, _, infos = venv.step(rng.integers(0, 10, venv.num_envs))
        frames.append(obs)
        rewards.append(reward)
        statuses.append([i["status"] for i in infos])
    venv.close()
    return np.stack(frames), np.stack(rewards), statuses


def test_remote_rollout_matches_a_local_one(simulation_worker, redis_url, settings):
    from training import dispatch
    from training.rollout.remote import RemoteVecEnv

    launch_simulation_worker = functools.partial(dispatch.send, dispatch.SIMULATE_ROLLOUT)
    spec = EnvSpec(track="racecraft_summit")
    remote = RemoteVecEnv(spec, 4, REWARD, launch=launch_simulation_worker, num_slots=2,
                          redis_url=redis_url, prefix=settings.REDIS_PREFIX)  # fmt: skip
    assert remote.sizes == [2, 2]
    local = SandboxedVecEnv(spec, 4, REWARD, num_workers=2)
    rf, rr, rs = run(remote)
    lf, lr, ls = run(local)
    assert np.array_equal(rf, lf)
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
