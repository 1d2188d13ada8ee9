"""The training loop, as DeepRacer runs it, on stable-baselines3: one loop whatever the
simulation. No Django here: the job that runs it (``training.worker``) passes in a backend
(:mod:`training.rollout.backends`), which picks where experience comes from (an
:class:`~training.rollout.experience.ExperienceSource`: envs stepped in lockstep here, or
simulation workers that stream whole episodes), and turns the hooks into database rows, stored
objects and websocket messages.

One iteration, as SB3's ``learn()``: the source gathers about ``num_episodes_between_training``
episodes with the current policy; the policy is updated (PPO's ``train``; SAC learns as it
drives); the source has the new policy evaluated (at once in lockstep; by the simulation
workers during the next rollout when streamed); when its evaluation is in, a metrics row, the
sim-trace of the iteration and the checkpoint (best and last) go to the hooks. The stop flag
and the time limit are checked on every step and between phases, so stopping always leaves the
last finished iteration's checkpoint. With ``stop_when_ready`` the run also ends once that many
evaluations in a row have completed every lap ("ready"): the iteration that completes the
streak is the best checkpoint, and the rollout under way then is not learnt from.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from stable_baselines3.common.logger import Logger

from training.rl.algorithms import build_model, load_model, resolve_device, set_torch_threads
from training.rl.hyperparams import Hyperparameters
from training.rl.policies import LEAN
from training.rollout.backends import LocalRollouts, RolloutBackend
from training.rollout.envs import EnvSpec
from training.rollout.experience import (
    EvaluationOutcome,
    Experience,
    ExperienceRequest,
    ExperienceSource,
)

log = logging.getLogger(__name__)


@dataclass
class TrainingConfig:
    """What to train and how. ``reward_source`` (a user's code, run sandboxed) or
    ``reward_function`` (a trusted callable, run in-process) gives the reward."""

    spec: EnvSpec
    algorithm: str = "clipped_ppo"
    network: str = LEAN
    hyperparameters: Hyperparameters = field(default_factory=Hyperparameters)
    max_minutes: float = 10.0
    stop_when_ready: int = 0
    """Stop once this many evaluations in a row have completed every lap (0: off; the time
    limit holds either way). The iteration that completes the streak becomes the best one,
    and the run ends ``"ready"``."""
    clean_streak: int = 0
    """Evaluations in a row that completed every lap before this run (a job resumed after its
    worker was lost: the latest of its recorded iterations); ``stop_when_ready`` counts on."""
    reward_source: str | None = None
    reward_function: Callable[[dict], float] | None = None
    num_envs: int = 8
    rollouts: RolloutBackend = field(default_factory=LocalRollouts)
    """Where the experience comes from (:mod:`training.rollout.backends`)."""
    seed: int = 0
    eval_episodes: int = 5
    eval_laps: int = 1
    eval_from_start_line: bool = False
    initial_checkpoint: bytes | None = None
    best_score: float | None = None
    """The best evaluation progress so far (a resumed model's): an iteration is "best", and
    replaces the best checkpoint, only when it does better. None: the first one is best."""
    torch_threads: int = 2
    """Threads of a policy update, at most: PPO's update in lockstep leaves a core to the
    evaluation that runs beside it (one thread on a 2-core machine, where one thread also
    updated faster than two: 3.1 against 3.6 s, bench/bench_update.py on an AMD EPYC)."""
    inference_threads: int = 1
    """Threads while PPO's trainer drives the cars and evaluates: a batch of 8 frames between
    the simulators' replies is too small to share, and a second thread's wake-up costs more
    than it saves (one forward pass, 8 frames, threads waiting passively as in every console
    process: 1.3 against 2.8 ms on a 2-core AMD EPYC)."""
    device: str = "auto"
    """Where the trainer's networks live (:func:`~training.rl.algorithms.resolve_device`)."""
    lagged_rollout: bool = False
    """An experiment, off: :attr:`~training.rollout.experience.ExperienceRequest.lagged_rollout`."""


@dataclass
class IterationResult:
    """One metrics row: DeepRacer's reward graph plus where the time went (seconds of the
    rollout, of the policy update and of the evaluation episodes)."""

    iteration: int
    episodes: int
    steps: int
    total_steps: int
    train_reward: float
    train_progress: float
    evaluation: EvaluationOutcome
    elapsed_s: float
    rollout_s: float
    update_s: float
    eval_s: float
    best: bool = False

    @property
    def eval_progress(self) -> float:
        return self.evaluation.mean_progress


class TrainingHooks:
    """What the loop tells the outside world; override what you need."""

    def should_stop(self) -> bool:
        return False

    def frames_wanted(self) -> bool:
        return False

    def on_episode(self, entry: dict) -> None:
        """A finished training episode (a TrainingMetrics.json entry)."""

    def on_frame(self, frame: dict) -> None:
        """A live video frame: JPEG bytes of the camera and the chase view."""

    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list[list]) -> None:
        """A finished iteration: its metrics, the model (SB3 zip bytes), its sim-trace rows."""


@dataclass
class TrainingSummary:
    iterations: int
    total_steps: int
    best_iteration: int | None
    best_eval_progress: float
    stopped_by: str
    elapsed_s: float


def machine_cores() -> int:
    """The cores this process may run on (its affinity, a container's cpuset)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def update_threads(threads: int, spare: int) -> int:
    """``threads``, or fewer so that ``spare`` of this machine's cores stay free; one at least."""
    return max(1, min(threads, machine_cores() - spare)) if spare else max(1, threads)


def evaluation_spec(config: TrainingConfig) -> EnvSpec:
    """The env of evaluation episodes: the training env, or from the start line for a
    several-lap evaluation; always in the clean world (the outside-world conditions are for
    training episodes only: the best checkpoint is the best in the world it races in)."""
    if config.eval_laps > 1 or config.eval_from_start_line:
        return EnvSpec.from_json(
            {**config.spec.to_json(), "start": "start_line", "alternate_direction": False,
             "rules": {**config.spec.rules, "laps": config.eval_laps}}
        ).clean()  # fmt: skip
    return config.spec.clean()


def experience_request(config: TrainingConfig) -> ExperienceRequest:
    """What the experience source needs to know of ``config``."""
    return ExperienceRequest(
        spec=config.spec, eval_spec=evaluation_spec(config), algorithm=config.algorithm,
        network=config.network, hyperparameters=dataclasses.asdict(config.hyperparameters),
        episodes_per_update=config.hyperparameters.num_episodes_between_training,
        num_envs=config.num_envs, eval_episodes=config.eval_episodes,
        spread_eval_starts=config.eval_laps == 1 and not config.eval_from_start_line,
        seed=config.seed, reward_source=config.reward_source,
        reward_function=config.reward_function, lagged_rollout=config.lagged_rollout,
    )  # fmt: skip


class TrainingLoop:
    """Runs iterations until the time limit or a stop request (see the module's docstring).
    Use :func:`train`."""

    def __init__(self, config: TrainingConfig, hooks: TrainingHooks | None = None) -> None:
        self.config = config
        self.hooks = hooks or TrainingHooks()
        self.started = time.monotonic()
        self.deadline = self.started + config.max_minutes * 60
        self._stop: str | None = None
        self._iteration = 0
        self._waiting: deque[tuple[IterationResult, bytes, list[list]]] = deque()
        self.emitted = 0
        self.total_steps = 0
        self.best_progress = -1.0 if config.best_score is None else float(config.best_score)
        self.best_iteration: int | None = None
        self.clean_streak = max(0, int(config.clean_streak))
        """Evaluations in a row, up to the latest, that completed every lap."""
        set_torch_threads(config.torch_threads)
        device = resolve_device(config.device)  # before any process starts: fail fast
        self.source: ExperienceSource = config.rollouts.experience(experience_request(config))
        try:
            if config.initial_checkpoint is not None:
                self.model = load_model(config.algorithm, config.initial_checkpoint,
                                        self.source.env, config.hyperparameters,
                                        network=config.network, seed=config.seed,
                                        device=device)  # fmt: skip
            else:
                self.model = build_model(config.algorithm, self.source.env, config.hyperparameters,
                                         network=config.network, seed=config.seed,
                                         device=device)  # fmt: skip
            self.model.set_logger(Logger(folder=None, output_formats=[]))
        except BaseException:
            self.source.close()
            raise

    @property
    def iteration(self) -> int:
        """Policy updates finished so far."""
        return self._iteration

    def stop_reason(self) -> str | None:
        if self._stop is None:
            if time.monotonic() >= self.deadline:
                self._stop = "time_limit"
            elif self.hooks.should_stop():
                self._stop = "user"
        return self._stop

    def run(self) -> TrainingSummary:
        try:
            self._threads(inference=True)  # the update sets its own and gives them back
            while not self.stop_reason():
                experience = self.source.gather(self)
                if experience is None:
                    break  # an interrupted rollout is not learnt from
                t1 = time.monotonic()
                if experience.learned_s is None:
                    self._update(experience)
                update_s = time.monotonic() - t1 + (experience.learned_s or 0.0)
                if self.stop_reason():
                    break  # stopped during the update: the last finished iteration stands
                self._iteration += 1
                rewards = [r for r, _ in experience.episodes]
                progress = [p for _, p in experience.episodes]
                result = IterationResult(
                    iteration=self._iteration, episodes=len(experience.episodes),
                    steps=experience.steps, total_steps=self.model.num_timesteps,
                    train_reward=float(np.mean(rewards)) if rewards else 0.0,
                    train_progress=float(np.mean(progress)) if progress else 0.0,
                    evaluation=EvaluationOutcome([], [], [], []), elapsed_s=0.0,
                    rollout_s=experience.rollout_s, update_s=update_s, eval_s=0.0,
                )  # fmt: skip
                self._waiting.append((result, self.checkpoint(), experience.rows))
                self.source.evaluate(self, self._iteration)
            self.source.finish(self)
        finally:
            self._threads(inference=False)
            self.close()
        return TrainingSummary(
            iterations=self.emitted,
            total_steps=self.total_steps,
            best_iteration=self.best_iteration,
            best_eval_progress=max(self.best_progress, 0.0),
            stopped_by=self._stop or "finished",
            elapsed_s=time.monotonic() - self.started,
        )

    def _update(self, experience: Experience) -> None:
        """PPO's update of ``experience``. It leaves the cores the experience asks for to its
        source and calls the experience's ``between_minibatches`` between two minibatches;
        a stop ends the update there (it is then not kept)."""
        self._threads(inference=False, spare=experience.spare_cores)
        beside = experience.between_minibatches

        def between_minibatches() -> bool:
            if beside is not None:
                beside()
            return self.stop_reason() is not None

        hooked = hasattr(self.model, "between_minibatches")  # DeepRacerPPO's hook
        if hooked:
            self.model.between_minibatches = between_minibatches
        try:
            self.model.train()
        finally:
            if hooked:
                self.model.between_minibatches = None
            self._threads(inference=True)

    def _threads(self, *, inference: bool, spare: int = 0) -> None:
        """PPO's inference threads, or the update's (SAC learns while it drives: the update's),
        leaving ``spare`` of this machine's cores to others (one thread at least)."""
        on_policy = self.config.algorithm == "clipped_ppo"
        threads = self.config.inference_threads if inference and on_policy else None
        set_torch_threads(update_threads(threads or self.config.torch_threads, spare))

    def evaluated(self, iteration: int, outcome: EvaluationOutcome, wall_s: float) -> None:
        """An iteration's evaluation is in: its metrics row, checkpoint and sim-trace go out."""
        while self._waiting and self._waiting[0][0].iteration < iteration:
            self._waiting.popleft()  # never evaluated (sources hand back in order)
        if not self._waiting or self._waiting[0][0].iteration != iteration:
            return
        result, checkpoint, rows = self._waiting.popleft()
        result.evaluation, result.eval_s = outcome, wall_s
        result.elapsed_s = time.monotonic() - self.started
        self.clean_streak = self.clean_streak + 1 if outcome.all_laps_complete else 0
        ready = 0 < self.config.stop_when_ready <= self.clean_streak
        if outcome.mean_progress > self.best_progress or ready:
            self.best_progress = max(self.best_progress, outcome.mean_progress)
            self.best_iteration, result.best = iteration, True
        if ready and self._stop is None:
            self._stop = "ready"  # the rollout under way is not learnt from
        self.emitted += 1
        self.total_steps = result.total_steps
        self.hooks.on_iteration(result, checkpoint, rows)

    def checkpoint(self) -> bytes:
        buffer = io.BytesIO()
        self.model.save(buffer)
        return buffer.getvalue()

    def close(self) -> None:
        self.source.close()


def train(config: TrainingConfig, hooks: TrainingHooks | None = None) -> TrainingSummary:
    """Train until ``config.max_minutes`` pass, ``hooks.should_stop()`` says so or (with
    ``config.stop_when_ready``) the model is ready."""
    return TrainingLoop(config, hooks).run()
