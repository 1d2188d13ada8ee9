"""Where a training job's experience comes from. The job that starts the loop
(``training.worker``) picks a backend; the backend picks the experience source for the run
(:mod:`training.rollout.experience`), so the loop never learns which one it got.

- :class:`LocalRollouts`: the trainer steps envs in lockstep, in sandboxed worker processes on
  this machine (a user's reward) or in its own process for a trusted callable (tests,
  benchmarks).
- :class:`StreamRollouts`: simulation workers that own their episodes and stream them through
  Redis, as local processes or as tasks on the ``simulation`` queue of other machines (how a
  worker is started is a callable the job passes in, so this package knows nothing of Celery).
  It serves PPO on a user's camera-only reward; SAC (which learns after every step, so it cannot
  wait on the network), a trusted in-process reward (which cannot travel) and a LIDAR
  observation run in lockstep on the trainer's machine instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from gymnasium import spaces
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from training.rollout.envs import EnvSpec
from training.rollout.experience import ExperienceRequest, ExperienceSource, RewardCallable
from training.rollout.lockstep import LockstepExperience
from training.rollout.streamed import LaunchWorker, StreamedExperience
from training.rollout.vecenv import LocalVecEnv, SandboxedVecEnv


class RolloutBackend(Protocol):
    """Builds the experience source of one training run."""

    def experience(self, request: ExperienceRequest) -> ExperienceSource: ...


def make_envs(spec: EnvSpec, num_envs: int, *, reward_source: str | None,
              reward_function: RewardCallable | None, num_workers: int = 2) -> VecEnv:  # fmt: skip
    """``num_envs`` envs of ``spec`` stepped together: in ``num_workers`` sandboxed processes for a
    user's ``reward_source``, in this process for a trusted ``reward_function``."""
    if reward_source is not None:
        return SandboxedVecEnv(spec, num_envs, reward_source, num_workers=num_workers)
    return LocalVecEnv(spec, num_envs, reward_function)


@dataclass(frozen=True)
class LocalRollouts:
    """Lockstep: ``num_workers`` sandboxed processes on this machine drive the training cars,
    one more drives the evaluation episodes (PPO: beside the next rollout, unless
    ``overlap_evaluation`` is False; see :class:`LockstepExperience`). PPO's camera networks
    drive the training cars in the workers, the actions drawn there, unless
    ``sample_in_workers`` is False (the trainer chooses every step's actions, SB3's way)."""

    num_workers: int = 2
    overlap_evaluation: bool = True
    sample_in_workers: bool = True

    def experience(self, request: ExperienceRequest) -> ExperienceSource:
        kwargs = {"reward_source": request.reward_source,
                  "reward_function": request.reward_function}  # fmt: skip
        venv = make_envs(request.spec, request.num_envs, num_workers=self.num_workers, **kwargs)
        try:
            eval_venv = make_envs(request.eval_spec, request.eval_episodes, num_workers=1,
                                  **kwargs)  # fmt: skip
        except BaseException:
            venv.close()
            raise
        return LockstepExperience(request, venv, eval_venv,
                                  overlap_evaluation=self.overlap_evaluation,
                                  sample_in_workers=self.sample_in_workers)  # fmt: skip


@dataclass(frozen=True)
class StreamRollouts:
    """``workers`` simulation workers, each started by ``launch`` (a local process, or a Celery
    task on the ``simulation`` queue), talking to the trainer through the Redis at
    ``redis_url``. What they cannot serve runs as :class:`LocalRollouts` with as many workers
    (see the module's docstring)."""

    redis_url: str
    launch: LaunchWorker
    workers: int = 2
    prefix: str = ""

    def experience(self, request: ExperienceRequest) -> ExperienceSource:
        if request.on_policy and request.reward_source is not None:
            env = DummyVecEnv([lambda: request.spec.make(None)])  # its spaces; never stepped
            if isinstance(env.observation_space, spaces.Box):
                return StreamedExperience(request, env, redis_url=self.redis_url,
                                          workers=self.workers, launch=self.launch,
                                          prefix=self.prefix)  # fmt: skip
            env.close()
        return LocalRollouts(num_workers=self.workers).experience(request)
