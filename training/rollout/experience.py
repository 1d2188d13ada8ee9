"""What the one training loop (:class:`training.rl.runner.TrainingLoop`) asks of the place its
experience comes from, as stable-baselines3's ``learn()`` asks ``collect_rollouts``.

An iteration: :meth:`ExperienceSource.gather` drives about ``episodes_per_update`` episodes
with the current policy and leaves them where the algorithm learns from (PPO's rollout buffer,
filled by :func:`~training.rollout.buffers.fill_rollout_buffer`; SAC learns as it drives); the
loop updates the policy, leaving the cores and calling back between minibatches as the
:class:`Experience` says; :meth:`ExperienceSource.evaluate` has the new policy evaluated, and
the source hands each finished evaluation back through :meth:`Learner.evaluated`, then or
later. Whatever a source does beside the update (lockstep: the evaluation of the policy before)
it keeps to itself. Two sources implement it:

- :class:`~training.rollout.lockstep.LockstepExperience`: the trainer steps vectorised envs
  (sandboxed processes on this machine), then evaluates on an env of its own;
- :class:`~training.rollout.streamed.StreamedExperience`: simulation workers, here or on other
  machines, own whole episodes and stream them through Redis; they drive the evaluation laps
  while the trainer updates.

A backend (:mod:`training.rollout.backends`) picks the source for a job; the loop never learns
which one it got.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from training.rollout.envs import EnvSpec

RewardCallable = Callable[[dict], float]


@dataclass
class EvaluationOutcome:
    """Deterministic-policy episodes after an update: one progress, status, lap-time list and
    reward per episode."""

    progress: list[float]
    """Of the lap each episode ended in (every lap counts from 0 to 100)."""
    statuses: list[str]
    lap_times: list[list[float]]
    rewards: list[float]
    ended_in_lap: list[int] = field(default_factory=list)
    """The lap (1, 2, ...) each episode ended in, where the source knows it (lockstep)."""

    @property
    def mean_progress(self) -> float:
        return float(np.mean(self.progress)) if self.progress else 0.0

    @property
    def all_laps_complete(self) -> bool:
        return bool(self.statuses) and all(s == "lap_complete" for s in self.statuses)


@dataclass(frozen=True)
class ExperienceRequest:
    """What a source needs to know of a training run (built by the loop from its config)."""

    spec: EnvSpec
    eval_spec: EnvSpec
    algorithm: str
    network: str
    hyperparameters: dict[str, Any]
    """DeepRacer's hyperparameters by name (``dataclasses.asdict`` of the loop's)."""
    episodes_per_update: int
    num_envs: int
    eval_episodes: int
    spread_eval_starts: bool
    """Evaluation episodes start spread round the track (False: all from the start line)."""
    seed: int = 0
    reward_source: str | None = None
    reward_function: RewardCallable | None = field(default=None, compare=False)
    lagged_rollout: bool = False
    """An experiment (off by default: it changes what the learner sees for a seed): where the
    workers draw the training cars' actions (lockstep PPO, camera networks), each rollout
    after the first is driven beside the update before it, with the policy of the rollout
    before (one update behind; its own values and log-probabilities go in the buffer)."""

    @property
    def on_policy(self) -> bool:
        """PPO learns from one rollout of the current policy; SAC learns as it drives."""
        return self.algorithm == "clipped_ppo"

    def eval_starts(self) -> list[float]:
        """Where each evaluation episode starts (% of the lap; -1: the start line)."""
        n = self.eval_episodes
        if not self.spread_eval_starts:
            return [-1.0] * n
        return [100.0 * i / n for i in range(n)]


@dataclass
class Experience:
    """What one :meth:`ExperienceSource.gather` brought in."""

    steps: int
    """Environment steps learnt from."""
    episodes: list[tuple[float, float]]
    """(total reward, progress %) of every training episode that finished."""
    rows: list[list]
    """The sim-trace rows of those steps (DeepRacer's 19 columns)."""
    rollout_s: float
    """Seconds spent driving."""
    learned_s: float | None = None
    """Seconds of policy updates already made while driving (SAC); None: the loop updates."""
    spare_cores: int = 0
    """Cores of this machine that the update learning from it leaves to the source (which
    drives on beside it), the same for every update of a run: 1 and 2 threads round
    differently, so a run's arithmetic must not depend on timing."""
    between_minibatches: Callable[[], object] | None = None
    """Called between two minibatches of that update (lockstep: hands back the evaluation
    driven beside it once it has ended; with ``lagged_rollout``, takes in the chunks of the
    next rollout, driven beside it)."""


class Hooks(Protocol):
    """The part of the loop's hooks a source talks to."""

    def frames_wanted(self) -> bool: ...

    def on_episode(self, entry: dict) -> None: ...

    def on_frame(self, frame: dict) -> None: ...


class Learner(Protocol):
    """What a source sees of the loop."""

    model: Any
    """The stable-baselines3 algorithm being trained."""
    hooks: Hooks

    @property
    def iteration(self) -> int:
        """Iterations finished so far."""
        ...

    def stop_reason(self) -> str | None: ...

    def evaluated(self, iteration: int, outcome: EvaluationOutcome, wall_s: float) -> None:
        """The evaluation of ``iteration``'s policy is in (``wall_s``: seconds it took)."""
        ...


class ExperienceSource(Protocol):
    """Where the loop's experience comes from (see the module's docstring)."""

    env: VecEnv
    """The env the algorithm is built on: its observation and action spaces, and for a
    lockstep source the env it steps."""

    def gather(self, learner: Learner) -> Experience | None:
        """Experience of the current policy; None when a stop interrupted it (not learnt).
        The first call starts whatever the source runs (the model is built by then)."""

    def evaluate(self, learner: Learner, iteration: int) -> None:
        """Have the policy as it is now (after ``iteration``'s update) evaluated. A source may
        first hand back an evaluation that ran beside the update; if that stops the loop,
        ``iteration`` is not evaluated (nor kept), as if the stop came during the update."""

    def finish(self, learner: Learner) -> None:
        """The run ends: hand back the evaluations still outstanding, as far as they got."""

    def close(self) -> None:
        """Release every process, thread and key (also after an error)."""
