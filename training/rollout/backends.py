"""Where rollouts run. The training loop asks a backend for vectorised envs and never learns
which one it got; the job that starts the loop (``training.worker``) chooses it.

- :class:`LocalRollouts`: sandboxed worker processes on this machine (a user's reward), or the
  trainer's own process for a trusted callable (tests, benchmarks).
- :class:`RedisRollouts`: sandboxed workers on other machines, reached through Redis. How a
  worker is started there (a Celery task on the ``simulation`` queue) is a callable the job
  passes in, so this package knows nothing of Celery.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from stable_baselines3.common.vec_env import VecEnv

from training.rollout.envs import EnvSpec
from training.rollout.remote import LaunchWorker, RemoteVecEnv
from training.rollout.vecenv import LocalVecEnv, RolloutError, SandboxedVecEnv

RewardCallable = Callable[[dict], float]


class RolloutBackend(Protocol):
    """Makes the envs one phase of training drives."""

    def make(
        self,
        spec: EnvSpec,
        num_envs: int,
        *,
        reward_source: str | None,
        reward_function: RewardCallable | None,
        phase: str,
    ) -> VecEnv: ...


@dataclass(frozen=True)
class LocalRollouts:
    """``num_workers`` sandboxed processes on this machine for a user's ``reward_source``;
    the trainer's own process for a trusted ``reward_function``."""

    num_workers: int = 2

    def make(
        self,
        spec: EnvSpec,
        num_envs: int,
        *,
        reward_source: str | None,
        reward_function: RewardCallable | None,
        phase: str,
    ) -> VecEnv:
        if reward_source is not None:
            return SandboxedVecEnv(spec, num_envs, reward_source, num_workers=self.num_workers)
        return LocalVecEnv(spec, num_envs, reward_function)


@dataclass(frozen=True)
class RedisRollouts:
    """``slots`` sandboxed workers on simulation machines, each started by ``launch`` and
    exchanging messages with the trainer through the Redis at ``redis_url``."""

    launch: LaunchWorker
    redis_url: str
    slots: int
    prefix: str = ""

    def make(
        self,
        spec: EnvSpec,
        num_envs: int,
        *,
        reward_source: str | None,
        reward_function: RewardCallable | None,
        phase: str,
    ) -> VecEnv:
        if reward_source is None:
            raise RolloutError("remote rollouts run a reward function's source, not a callable")
        return RemoteVecEnv(
            spec,
            num_envs,
            reward_source,
            launch=self.launch,
            num_slots=self.slots,
            redis_url=self.redis_url,
            prefix=self.prefix,
            phase=phase,
        )


@dataclass(frozen=True)
class StreamRollouts:
    """Simulation workers that own their episodes (:mod:`training.rollout.streams`): ``workers``
    of them, each started by ``launch`` (a Celery task on the ``simulation`` queue), or as
    processes of this machine when ``launch`` is None, all talking to the trainer through the
    Redis at ``redis_url``. The training loop drives PPO this way; SAC, which learns as it
    drives, and trusted in-process rewards keep the lockstep envs of :meth:`make`."""

    redis_url: str
    workers: int = 2
    launch: LaunchWorker | None = None
    prefix: str = ""
    streamed = True

    def make(
        self,
        spec: EnvSpec,
        num_envs: int,
        *,
        reward_source: str | None,
        reward_function: RewardCallable | None,
        phase: str,
    ) -> VecEnv:
        return LocalRollouts(num_workers=self.workers).make(
            spec, num_envs, reward_source=reward_source, reward_function=reward_function,
            phase=phase,
        )  # fmt: skip
