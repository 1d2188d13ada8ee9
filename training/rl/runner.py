"""The training loop, as DeepRacer runs it, on stable-baselines3. No Django here: the job that
runs it (``training.worker``) passes in where rollouts run (a :class:`RolloutBackend`) and
turns the hooks into database rows, stored objects and websocket messages.

One iteration: the rollout workers drive about ``num_episodes_between_training`` episodes with
the current policy; the policy is updated; evaluation episodes measure the new policy's track
completion; a metrics row, the sim-trace of the iteration and the checkpoint (best and last) go
to the hooks. The stop flag and the time limit are checked on every step and between phases, so
stopping always leaves the last finished iteration's checkpoint.
"""

from __future__ import annotations

import copy
import io
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from training.rl.algorithms import (
    DeepRacerPPO,
    build_model,
    load_model,
    plan_rollout_steps,
    resolve_device,
    set_torch_threads,
)
from training.rl.hyperparams import Hyperparameters
from training.rl.policies import LEAN
from training.rollout.backends import LocalRollouts, RolloutBackend
from training.rollout.envs import FRAME_INTERVAL_S, EnvSpec

log = logging.getLogger(__name__)

INITIAL_EPISODE_STEPS = 40.0
"""Guess of an early episode's length (steps) before any has finished."""
MAX_SAC_CHUNKS = 200
"""An SAC iteration ends after this many chunks even if fewer episodes finished."""


@dataclass
class TrainingConfig:
    """What to train and how. ``reward_source`` (a user's code, run sandboxed) or
    ``reward_function`` (a trusted callable, run in-process) gives the reward."""

    spec: EnvSpec
    algorithm: str = "clipped_ppo"
    network: str = LEAN
    hyperparameters: Hyperparameters = field(default_factory=Hyperparameters)
    max_minutes: float = 10.0
    reward_source: str | None = None
    reward_function: Callable[[dict], float] | None = None
    num_envs: int = 8
    rollouts: RolloutBackend = field(default_factory=LocalRollouts)
    """Where training episodes run; evaluation episodes always run on this machine."""
    seed: int = 0
    eval_episodes: int = 5
    eval_laps: int = 1
    eval_from_start_line: bool = False
    initial_checkpoint: bytes | None = None
    best_score: float | None = None
    """The best evaluation progress so far (a resumed model's): an iteration is "best", and
    replaces the best checkpoint, only when it does better. None: the first one is best."""
    torch_threads: int = 2
    device: str = "auto"
    """Where the trainer's networks live (:func:`~training.rl.algorithms.resolve_device`)."""


@dataclass
class EvaluationOutcome:
    """Deterministic-policy episodes after an update."""

    progress: list[float]
    statuses: list[str]
    lap_times: list[list[float]]
    rewards: list[float]

    @property
    def mean_progress(self) -> float:
        return float(np.mean(self.progress)) if self.progress else 0.0

    @property
    def all_laps_complete(self) -> bool:
        return bool(self.statuses) and all(s == "lap_complete" for s in self.statuses)


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


def evaluation_spec(config: TrainingConfig) -> EnvSpec:
    """The env of evaluation episodes: the training env, or from the start line for a
    several-lap evaluation."""
    if config.eval_laps > 1 or config.eval_from_start_line:
        return EnvSpec.from_json(
            {**config.spec.to_json(), "start": "start_line", "alternate_direction": False,
             "rules": {**config.spec.rules, "laps": config.eval_laps}}
        )  # fmt: skip
    return config.spec


class _StepWatcher(BaseCallback):
    """Collects what workers report each step and stops rollouts when asked to."""

    def __init__(self, loop: TrainingLoop) -> None:
        super().__init__()
        self.loop = loop

    def _on_step(self) -> bool:
        loop = self.loop
        for info in self.locals.get("infos", ()):
            loop.collect(info)
        if loop.hooks.frames_wanted() != loop.venv.want_frames:
            loop.venv.want_frames = loop.hooks.frames_wanted()
        return not loop.stop_reason()

    def _on_rollout_start(self) -> None:
        self.loop.spectator.stop()

    def _on_rollout_end(self) -> None:
        self.loop.rollout_done_at = time.monotonic()
        self.loop.spectator.start(self.loop._iteration + 1)


class _Spectator:
    """Keeps the live view going while the policy updates: drives the evaluation env with a
    frozen copy of the policy that drove the rollout, at the view's pace (15 steps a second of
    real time), from the rollout's end until the evaluation; and with the evaluated policy from
    the evaluation's end while the iteration is logged, until the next rollout. Only when
    someone watches. Its laps are for the eyes: nothing is scored or logged, and an error in
    one only ends it (the evaluation that follows reports it)."""

    def __init__(self, loop: TrainingLoop) -> None:
        self.loop = loop
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self, iteration: int) -> None:
        """Drive with the policy as it is now, labelled ``iteration`` (the one it belongs to)."""
        loop = self.loop
        if self._thread is not None or not isinstance(loop.model, DeepRacerPPO):
            return  # SAC learns between short stretches of driving: no long pause to fill
        if not loop.hooks.frames_wanted():
            return
        policy = copy.deepcopy(loop.model.policy)  # the update changes the trainer's in place
        policy.set_training_mode(False)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drive, args=(policy, iteration),
                                        name="spectator", daemon=True)  # fmt: skip
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None

    def _drive(self, policy, iteration: int) -> None:
        venv, hooks, stop = self.loop.eval_venv, self.loop.hooks, self._stop
        try:
            venv.want_frames = True
            obs = venv.reset()
            due = time.monotonic()
            while not stop.is_set():
                with torch.no_grad():
                    actions, _ = policy.predict(obs, deterministic=True)
                obs, _rewards, _dones, infos = venv.step(actions)  # ends reset by themselves
                frame = infos[0].pop("frame", None)
                if frame is not None:
                    hooks.on_frame({**frame, "phase": "evaluation", "iteration": iteration,
                                    "spare": True})  # fmt: skip
                due += FRAME_INTERVAL_S
                stop.wait(max(0.0, due - time.monotonic()))
        except Exception:  # noqa: BLE001 - the video is never worth the training
            log.warning("the live view's lap during the update stopped", exc_info=True)


class TrainingLoop:
    """Runs iterations until the time limit or a stop request. Use :func:`train`."""

    def __init__(self, config: TrainingConfig, hooks: TrainingHooks | None = None) -> None:
        self.config = config
        self.hooks = hooks or TrainingHooks()
        self.started = time.monotonic()
        self.deadline = self.started + config.max_minutes * 60
        self.rows: list[list] = []
        self.episode_steps: list[int] = []
        self.episode_rewards: list[float] = []
        self.episode_progress: list[float] = []
        self._stop: str | None = None
        self.rollout_done_at = 0.0
        self._iteration = 0
        self.spectator = _Spectator(self)
        self.longest_seen = 0  # steps of the longest episode seen so far, finished or not
        set_torch_threads(config.torch_threads)
        device = resolve_device(config.device)  # before any process starts: fail fast
        self.venv: VecEnv = config.rollouts.make(
            config.spec,
            config.num_envs,
            reward_source=config.reward_source,
            reward_function=config.reward_function,
            phase="training",
        )
        self.eval_venv: VecEnv = LocalRollouts(num_workers=1).make(
            evaluation_spec(config),
            config.eval_episodes,
            reward_source=config.reward_source,
            reward_function=config.reward_function,
            phase="evaluation",
        )
        self.venv.seed(config.seed)
        if config.initial_checkpoint is not None:
            self.model = load_model(
                config.algorithm,
                config.initial_checkpoint,
                self.venv,
                config.hyperparameters,
                network=config.network,
                seed=config.seed,
                device=device,
            )
        else:
            self.model = build_model(
                config.algorithm,
                self.venv,
                config.hyperparameters,
                network=config.network,
                seed=config.seed,
                device=device,
            )

    # -------------------------------------------------------------------- step bookkeeping
    def collect(self, info: dict) -> None:
        trace = info.get("trace")
        if trace is not None:
            self.rows.append(trace)
            if isinstance(trace[1], int) and trace[1] > self.longest_seen:
                self.longest_seen = trace[1]
        frame = info.get("frame")
        if frame is not None:
            self.hooks.on_frame({**frame, "phase": "training", "iteration": self._iteration + 1})
        entry = info.get("episode_entry")
        if entry is not None:
            self.episode_steps.append(int(entry.get("steps", 0)))
            self.episode_rewards.append(float(entry.get("total_reward", 0.0)))
            self.episode_progress.append(float(entry.get("progress", 0.0)))
            self.hooks.on_episode(entry)

    def stop_reason(self) -> str | None:
        if self._stop is None:
            if time.monotonic() >= self.deadline:
                self._stop = "time_limit"
            elif self.hooks.should_stop():
                self._stop = "user"
        return self._stop

    # -------------------------------------------------------------------- phases
    def _rollout_and_update(self) -> None:
        model = self.model
        hp = self.config.hyperparameters
        if isinstance(model, DeepRacerPPO):
            # PPO learns from one rollout: size it so that about N episodes fit in it.
            recent = self.episode_steps[-50:]
            mean_len = (
                float(np.mean(recent))
                if recent
                else max(INITIAL_EPISODE_STEPS, float(self.longest_seen))
            )
            n_steps = plan_rollout_steps(hp.num_episodes_between_training, mean_len, model.n_envs)
            model.set_rollout_steps(n_steps)
            self._learn(n_steps * model.n_envs)
            return
        # SAC learns as it drives: drive on in chunks until N more episodes have finished.
        target = len(self.episode_steps) + hp.num_episodes_between_training
        chunk = max(64, 16 * model.n_envs)
        for _ in range(MAX_SAC_CHUNKS):
            self._learn(chunk)
            if len(self.episode_steps) >= target or self.stop_reason():
                break

    def _learn(self, steps: int) -> None:
        self.model.learn(
            total_timesteps=steps,
            reset_num_timesteps=False,
            callback=_StepWatcher(self),
            progress_bar=False,
        )

    def evaluate(self) -> EvaluationOutcome:
        """One deterministic episode per eval env (starts spread round the track)."""
        venv = self.eval_venv
        n = venv.num_envs
        if not self.config.eval_from_start_line and self.config.eval_laps == 1:
            venv.set_options([{"start_progress": 100.0 * i / n} for i in range(n)])
        obs = venv.reset()
        done = np.zeros(n, dtype=bool)
        outcome = EvaluationOutcome([0.0] * n, [""] * n, [[] for _ in range(n)], [0.0] * n)
        iteration = self._iteration + 1
        while not done.all():
            # The live view shows the evaluation lap too: a gap only while the policy updates.
            venv.want_frames = self.hooks.frames_wanted()
            actions, _ = self.model.predict(obs, deterministic=True)
            obs, rewards, dones, infos = venv.step(actions)
            # The first car's frames (it drives on after its episode while the others finish).
            frame = infos[0].pop("frame", None)
            if frame is not None:
                self.hooks.on_frame({**frame, "phase": "evaluation", "iteration": iteration})
            for i in np.flatnonzero(~done):
                outcome.rewards[i] += float(rewards[i])
                info = infos[i]
                if dones[i]:
                    done[i] = True
                    outcome.progress[i] = float(info["progress"])
                    outcome.statuses[i] = str(info["status"])
                    outcome.lap_times[i] = list(info.get("lap_times", []))
            if self.stop_reason():
                break
        return outcome

    def run(self) -> TrainingSummary:
        best_progress, best_iteration = -1.0, None
        if self.config.best_score is not None:
            best_progress = float(self.config.best_score)
        total_steps = 0
        try:
            while not self.stop_reason():
                t0 = time.monotonic()
                first_episode = len(self.episode_steps)
                steps_before = self.model.num_timesteps
                try:
                    self._rollout_and_update()
                finally:
                    self.spectator.stop()
                t1 = time.monotonic()
                if self.stop_reason():
                    break  # an interrupted rollout was not learned from
                evaluation = self.evaluate()
                t2 = time.monotonic()
                self._iteration += 1
                total_steps = self.model.num_timesteps
                rewards = self.episode_rewards[first_episode:]
                progress = self.episode_progress[first_episode:]
                result = IterationResult(
                    iteration=self._iteration,
                    episodes=len(rewards),
                    steps=total_steps - steps_before,
                    total_steps=total_steps,
                    train_reward=float(np.mean(rewards)) if rewards else 0.0,
                    train_progress=float(np.mean(progress)) if progress else 0.0,
                    evaluation=evaluation,
                    elapsed_s=t2 - self.started,
                    rollout_s=max(0.0, self.rollout_done_at - t0),
                    update_s=max(0.0, t1 - max(self.rollout_done_at, t0)),
                    eval_s=t2 - t1,
                )
                if evaluation.mean_progress > best_progress:
                    best_progress, best_iteration = evaluation.mean_progress, self._iteration
                    result.best = True
                rows, self.rows = self.rows, []
                self.spectator.start(self._iteration)  # while the iteration is stored and logged
                self.hooks.on_iteration(result, self.checkpoint(), rows)
        finally:
            self.close()
        return TrainingSummary(
            iterations=self._iteration,
            total_steps=total_steps,
            best_iteration=best_iteration,
            best_eval_progress=max(best_progress, 0.0),
            stopped_by=self._stop or "finished",
            elapsed_s=time.monotonic() - self.started,
        )

    def checkpoint(self) -> bytes:
        buffer = io.BytesIO()
        self.model.save(buffer)
        return buffer.getvalue()

    def close(self) -> None:
        self.spectator.stop()
        for venv in (self.venv, self.eval_venv):
            try:
                venv.close()
            except Exception:  # noqa: BLE001 - closing must not hide the real error
                pass


def train(config: TrainingConfig, hooks: TrainingHooks | None = None) -> TrainingSummary:
    """Train until ``config.max_minutes`` pass or ``hooks.should_stop()`` says so, stepping the
    envs from here (jobs call :func:`training.rl.streamed.train`, which picks the way)."""
    return TrainingLoop(config, hooks).run()
