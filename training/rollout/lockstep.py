"""Experience in lockstep: the trainer steps vectorised envs (the sandboxed worker processes of
this machine, or its own process for a trusted reward), as DeepRacer's rollout workers did
with the trainer waiting; then the loop updates; then one deterministic episode per env of an
evaluation env of its own measures the new policy.

PPO's evaluation runs beside the next rollout, whose policy is the one it measures
(:class:`Evaluation`). For the camera networks its worker drives it: the network goes there
once, in NumPy, and the worker drives a chunk of steps a command, which the trainer takes up
between two training steps whenever they are there. For the others the trainer sends the
evaluation car its next action after each training step and takes the reply after the next,
so the evaluation worker steps while the trainer chooses the training cars' actions and waits
for their workers. What is left of it at the rollout's end runs beside the next update, on a
thread of its own (with a frozen copy of the policy, where the trainer drives), on a core the
update leaves it (:attr:`Experience.spare_cores`); its outcome goes back between two of the
update's minibatches once it ends (:attr:`Experience.between_minibatches`), or when the next
evaluation starts (:meth:`LockstepExperience.evaluate`). Nothing learnt
changes: the same steps, updates and outcomes as evaluating first (tested), in less time.
While an evaluation runs, its car is on the live view; the training cars' frames follow.

PPO's rollout fills the model's rollout buffer, sized before each update so that about
``episodes_per_update`` episodes fit in it; the loop's update is SB3's ``train``. With a camera
network (the policy's network can travel in NumPy, as for the evaluation) the workers drive the
training cars themselves: each draws its cars' actions from the policy's probabilities,
:data:`SAMPLE_STEPS` steps a command, two commands under way, and the trainer computes the
values and log-probabilities of the whole rollout in a few batches afterwards
(:meth:`LockstepExperience._sample_rollout`, :func:`fill_sampled_rollout`: what SB3's
``collect_rollouts`` would put in the buffer for the same actions, tested). No round trip and
no forward pass of the trainer's per step: on 2 cores a step of the rollout costs about two
thirds of what it did. Every other policy (camera + LIDAR, SAC, continuous actions), and
``sample_in_workers=False``, runs stable-baselines3's own ``collect_rollouts``, so that an
iteration is exactly what SB3's ``learn`` does. SAC learns as it drives (an update after every
step): it drives on in chunks of SB3's ``learn`` until that many more episodes have finished.

``lagged_rollout`` (an experiment, off: :attr:`ExperienceRequest.lagged_rollout`): where the
workers draw the actions, the next rollout starts as the update starts, with the policy that
drove the rollout just learnt from, and its chunks come in between the update's minibatches
(:meth:`LockstepExperience._beside_update`): the simulators drive on the core the update
leaves. The buffer then holds that policy's values and log-probabilities, one update behind
the policy that learns from it; a seed takes other steps than without it.

While the policy updates, and while an iteration is stored, a :class:`Spectator` keeps the live
view going when someone watches.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import logging
import math
import select
import threading
import time

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from training.rollout.buffers import fill_rollout_buffer
from training.rollout.envs import FRAME_INTERVAL_S
from training.rollout.experience import (
    EvaluationOutcome,
    Experience,
    ExperienceRequest,
    Learner,
)
from training.rollout.greedy import export_greedy, greedy_actions
from training.rollout.vecenv import DRIVE_STEPS, SampledSteps

log = logging.getLogger(__name__)

INITIAL_EPISODE_STEPS = 40.0
"""Guess of an early episode's length (steps) before any has finished."""
MAX_SAC_CHUNKS = 200
"""An SAC iteration ends after this many chunks even if fewer episodes finished."""
MIN_ROLLOUT_STEPS = 16
MAX_ROLLOUT_STEPS = 2048
SAMPLE_STEPS = 32
"""Steps of every training car that a worker drives per command of a sampled rollout (about
0.1 s for 4 cars): the trainer books one chunk while the workers drive the next."""
VALUE_BATCH = 64
"""Observations per forward pass when the values and log-probabilities of a sampled rollout
are computed after it."""
WATCHED_CHUNK_STEPS = 8
"""Steps of a chunk, the training cars' or the evaluation car's, while the live view shows
that car (about 30 ms for 4 cars): its frames then come about as they are driven."""
SAMPLES_AHEAD = 2
"""Chunks of a sampled rollout under way at once (:meth:`LockstepExperience._sample_rollout`)."""
WAIT_S = 0.05
"""Longest sleep between looks at the workers while a sampled chunk is under way."""


def plan_rollout_steps(episodes: int, mean_episode_steps: float, num_envs: int) -> int:
    """Steps per env so that about ``episodes`` episodes finish before the next update."""
    steps = math.ceil(episodes * max(mean_episode_steps, 1.0) / num_envs)
    return int(min(MAX_ROLLOUT_STEPS, max(MIN_ROLLOUT_STEPS, steps)))


@dataclasses.dataclass
class _Run:
    """A rollout that the workers drive (:meth:`LockstepExperience._sample_rollout`):
    ``n_steps`` a car with ``policy`` (whose values and log-probabilities go in the buffer),
    ``net`` and ``seed`` going with its first chunk; chunks sent, under way, and come in."""

    n_steps: int
    policy: object
    net: dict | None
    seed: int | None
    sent: int = 0
    in_flight: list[int] = dataclasses.field(default_factory=list)
    received: list[SampledSteps] = dataclasses.field(default_factory=list)


class _StepWatcher(BaseCallback):
    """Collects what the envs report each step and stops the rollout when asked to."""

    def __init__(self, source: LockstepExperience, learner: Learner) -> None:
        super().__init__()
        self.source, self.learner = source, learner

    def _on_step(self) -> bool:
        source, learner = self.source, self.learner
        for info in self.locals.get("infos", ()):
            source.collect(info, learner)
        # The live view shows the evaluation beside the rollout while there is one.
        wanted = learner.hooks.frames_wanted() and source.evaluating is None
        if wanted != source.venv.want_frames:
            source.venv.want_frames = wanted
        source.advance_evaluation(learner)
        return not learner.stop_reason()

    def _on_rollout_start(self) -> None:
        self.source.spectator.stop()

    def _on_rollout_end(self) -> None:
        self.source.rollout_ended(self.learner)


class Evaluation:
    """One evaluation: a deterministic episode per env of the eval env (one of
    :mod:`training.rollout.vecenv`'s, which step in two halves) with the policy as it is when
    it starts, so that it can run beside the next rollout; ``busy_s`` is the trainer's time
    spent on it.

    Where the policy's network can travel to the eval env's workers
    (:func:`~training.rollout.greedy.export_greedy`: PPO's camera networks), they drive it
    themselves, :data:`DRIVE_STEPS` steps a command, and the trainer only collects the steps
    when they are there (:meth:`ready`): no round trip and no inference of the trainer's per
    step. Otherwise the trainer chooses each step's action (:meth:`send`, then
    :meth:`receive`)."""

    def __init__(self, venv: VecEnv, request: ExperienceRequest, iteration: int,
                 policy=None) -> None:  # fmt: skip
        self.venv, self.iteration = venv, iteration
        n = venv.num_envs
        if request.spread_eval_starts:
            venv.set_options([{"start_progress": p} for p in request.eval_starts()])
        t0 = time.monotonic()
        self._net = (export_greedy(policy)
                     if policy is not None and hasattr(venv, "send_drive") else None)  # fmt: skip
        """The network for the workers to drive with, until it goes with the first chunk."""
        self.driven_by_workers = self._net is not None
        self.obs = venv.reset()
        self.done = np.zeros(n, dtype=bool)
        self.outcome = EvaluationOutcome([0.0] * n, [""] * n, [[] for _ in range(n)], [0.0] * n,
                                         [1] * n)  # fmt: skip
        self.in_flight = False
        self.busy_s = time.monotonic() - t0

    @property
    def finished(self) -> bool:
        return bool(self.done.all())

    def send(self, policy) -> None:
        """The next step (the trainer drives: ``policy``'s action) or chunk of steps (the
        workers drive: the network goes with the first)."""
        t0 = time.monotonic()
        if self.driven_by_workers:
            # Watched, shorter chunks: the car's frames come about as they are driven.
            steps = min(DRIVE_STEPS, WATCHED_CHUNK_STEPS) if self.venv.want_frames else DRIVE_STEPS
            self.venv.send_drive(self._net, steps)
            self._net = None  # the workers keep it
        else:
            self.venv.send_step(greedy_actions(policy, self.obs))
        self.in_flight = True
        self.busy_s += time.monotonic() - t0

    def ready(self) -> bool:
        """Whether :meth:`receive` would not wait for the workers."""
        return not self.driven_by_workers or self.venv.drive_ready()

    def drive(self, policy, hooks, *, want_frames, until=None) -> None:
        """Drive on to the end (or until ``until()`` says stop) with ``policy`` (not used when
        the workers drive); ``want_frames()`` says whether the live view wants the car's
        frames."""
        while not self.finished:
            if not self.in_flight:
                self.venv.want_frames = want_frames()
                self.send(policy)
            self.receive(hooks)
            if until is not None and until():
                break

    def receive(self, hooks) -> None:
        """The replies of the step or steps sent; the first car's frames go to ``hooks`` (it
        drives on after its episode while the others finish)."""
        t0 = time.monotonic()
        if self.driven_by_workers:
            steps = self.venv.receive_drive()
        else:
            self.obs, rewards, dones, infos = self.venv.receive_step()
            steps = [(rewards, dones, infos)]
        self.in_flight = False
        for rewards, dones, infos in steps:
            self._record(hooks, rewards, dones, infos)
        self.busy_s += time.monotonic() - t0

    def _record(self, hooks, rewards, dones, infos) -> None:
        frame = infos[0].pop("frame", None)
        if frame is not None:
            hooks.on_frame({**frame, "phase": "evaluation", "iteration": self.iteration})
        outcome = self.outcome
        for i in np.flatnonzero(~self.done):
            outcome.rewards[i] += float(rewards[i])
            info = infos[i]
            if dones[i]:
                self.done[i] = True
                outcome.progress[i] = float(info["progress"])
                outcome.statuses[i] = str(info["status"])
                outcome.lap_times[i] = list(info.get("lap_times", []))
                outcome.ended_in_lap[i] = int(info.get("lap", 1))


def fill_sampled_rollout(model, chunks: list[SampledSteps], policy=None) -> None:
    """``model``'s rollout buffer from a rollout its envs' side drove (``chunks`` in order, as
    many steps as the buffer holds): what SB3's ``collect_rollouts`` puts there, with the
    values and log-probabilities of ``policy`` (the one that drove it: ``model.policy`` by
    default) computed for all the steps at once, through
    :func:`~training.rollout.buffers.fill_rollout_buffer`. As SB3 does, an episode that the
    time limit cut gets γ × the value of its last observation added to its last reward, and
    the returns bootstrap from the value of the observations after the rollout.
    ``model._last_obs`` and ``_last_episode_starts`` move on as there.

    :raises RuntimeError: the chunks do not hold the buffer's steps × envs."""
    buffer = model.rollout_buffer
    policy = model.policy if policy is None else policy
    obs = np.concatenate([c.obs for c in chunks])
    actions = np.concatenate([c.actions for c in chunks])
    rewards = np.concatenate([c.rewards for c in chunks]).astype(np.float32)
    dones = np.concatenate([c.dones for c in chunks])
    infos = [step for c in chunks for step in c.infos]
    steps, n = actions.shape
    if steps != buffer.buffer_size or n != buffer.n_envs:
        raise RuntimeError(f"a rollout of {steps}×{n} steps for a buffer of "
                           f"{buffer.buffer_size}×{buffer.n_envs}")  # fmt: skip
    shape = policy.observation_space.shape

    def channels_first(frames: np.ndarray) -> np.ndarray:
        return frames if frames.shape[-3:] == shape else np.moveaxis(frames, -1, -3)

    flat = channels_first(obs.reshape(steps * n, *obs.shape[2:]))
    values = np.empty(steps * n, np.float32)
    log_probs = np.empty(steps * n, np.float32)
    with torch.no_grad():
        for start in range(0, steps * n, VALUE_BATCH):
            part = slice(start, start + VALUE_BATCH)
            tensor = torch.as_tensor(np.ascontiguousarray(flat[part]), device=model.device)
            chosen = torch.as_tensor(actions.reshape(-1)[part], device=model.device)
            v, lp, _ = policy.evaluate_actions(tensor, chosen)
            values[part] = v.flatten().cpu().numpy()
            log_probs[part] = lp.cpu().numpy()
        cut = [(t, i) for t in range(steps) for i in range(n)
               if dones[t, i] and infos[t][i].get("terminal_observation") is not None
               and infos[t][i].get("TimeLimit.truncated", False)]  # fmt: skip
        if cut:
            terminal = np.stack([infos[t][i]["terminal_observation"] for t, i in cut])
            tail = policy.predict_values(torch.as_tensor(channels_first(terminal),
                                                         device=model.device))  # fmt: skip
            for (t, i), value in zip(cut, tail.flatten().cpu().numpy(), strict=True):
                rewards[t, i] += model.gamma * value
        last = torch.as_tensor(channels_first(chunks[-1].next_obs), device=model.device)
        last_values = policy.predict_values(last)
    starts = np.empty((steps, n), np.float32)
    starts[0] = model._last_episode_starts
    starts[1:] = dones[:-1]
    fill_rollout_buffer(buffer, observations=flat, actions=actions, rewards=rewards,
                        episode_starts=starts, values=values, log_probs=log_probs,
                        last_values=last_values, dones=dones[-1])  # fmt: skip
    model._last_obs = channels_first(chunks[-1].next_obs)
    model._last_episode_starts = dones[-1]


def frozen_copy(policy):
    """A copy of ``policy`` to drive with while the update changes the trainer's in place:
    without its optimizer (twice the weights again, never used to drive), in eval mode."""
    optimizer = getattr(policy, "optimizer", None)
    memo = {} if optimizer is None else {id(optimizer): None}
    frozen = copy.deepcopy(policy, memo)
    frozen.set_training_mode(False)
    return frozen


class Spectator:
    """Drives the evaluation env while the policy updates, with a frozen copy of the policy
    that drove the rollout (the update changes the trainer's in place), on a thread of its own.

    - First, when given one, what is left of the evaluation of that policy, at full speed
      (PPO in lockstep: the evaluation runs beside the next rollout, then beside the update).
      The loop takes it back with :meth:`take_evaluation`, between the update's minibatches
      or after it; an error in it is raised there.
    - Then, only when someone watches, laps at the view's pace (15 steps a second of real
      time) to keep the live view going, until :meth:`stop`. Only for PPO (SAC has no long
      pause to fill). These laps are for the eyes: nothing is scored or logged, and an error
      in one only ends them.
    """

    def __init__(self, env: VecEnv, *, enabled: bool) -> None:
        self.env = env
        self.enabled = enabled
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._abort = threading.Event()
        self._evaluation: Evaluation | None = None
        self._evaluated = threading.Event()
        self._error: BaseException | None = None

    def start(self, learner: Learner, iteration: int, evaluation: Evaluation | None = None) -> None:
        """Drive with the policy as it is now, labelled ``iteration`` (the one it belongs to):
        ``evaluation`` to its end first, if given."""
        watched = self.enabled and learner.hooks.frames_wanted()
        if self._thread is not None or (evaluation is None and not watched):
            return
        needed = watched or (evaluation is not None and not evaluation.driven_by_workers)
        policy = frozen_copy(learner.model.policy) if needed else None
        self._stop, self._abort, self._evaluated = (threading.Event(), threading.Event(),
                                                    threading.Event())  # fmt: skip
        self._evaluation, self._error = evaluation, None
        if evaluation is None:
            self._evaluated.set()
        self._thread = threading.Thread(
            target=self._run, args=(policy, learner.hooks, iteration, evaluation, watched),
            name="spectator", daemon=True,
        )  # fmt: skip
        self._thread.start()

    def take_evaluation(self, *, wait: bool) -> Evaluation | None:
        """The evaluation given to :meth:`start` once it has ended (``wait``: wait for that),
        and only once; None when there is none, or (not ``wait``) it is still driving."""
        evaluation = self._evaluation
        if evaluation is None or (not wait and not self._evaluated.is_set()):
            return None
        self._evaluated.wait()
        self._evaluation, error, self._error = None, self._error, None
        if error is not None:
            raise error
        return evaluation

    def stop(self, *, abort: bool = False) -> None:
        """End the laps; an evaluation under way is driven to its end first, unless ``abort``."""
        if self._thread is not None:
            if abort:
                self._abort.set()
            self._stop.set()
            self._thread.join()
            self._thread = None

    def _run(self, policy, hooks, iteration: int, evaluation: Evaluation | None,
             watched: bool) -> None:  # fmt: skip
        if evaluation is not None:
            try:
                evaluation.drive(policy, hooks, want_frames=lambda: watched,
                                 until=self._abort.is_set)  # fmt: skip
            except BaseException as error:  # noqa: BLE001 - raised in the loop's thread
                self._error = error
            finally:
                self._evaluated.set()
            if self._error is not None or not watched:
                return
        self._drive(policy, hooks, iteration)

    def _drive(self, policy, hooks, iteration: int) -> None:
        venv, stop = self.env, self._stop
        try:
            venv.want_frames = True
            obs = venv.reset()
            due = time.monotonic()
            while not stop.is_set():
                actions = greedy_actions(policy, obs)
                obs, _rewards, _dones, infos = venv.step(actions)  # ends reset by themselves
                frame = infos[0].pop("frame", None)
                if frame is not None:
                    hooks.on_frame({**frame, "phase": "evaluation", "iteration": iteration,
                                    "spare": True})  # fmt: skip
                due += FRAME_INTERVAL_S
                stop.wait(max(0.0, due - time.monotonic()))
        except Exception:  # noqa: BLE001 - the video is never worth the training
            log.warning("the live view's lap during the update stopped", exc_info=True)


class LockstepExperience:
    """An :class:`~training.rollout.experience.ExperienceSource` stepping ``venv`` (training)
    and ``eval_venv`` (one deterministic episode per env after each update) from the trainer."""

    def __init__(self, request: ExperienceRequest, venv: VecEnv, eval_venv: VecEnv, *,
                 overlap_evaluation: bool = True,
                 sample_in_workers: bool = True) -> None:  # fmt: skip
        self.request = request
        self.venv = self.env = venv
        self.eval_venv = eval_venv
        self.venv.seed(request.seed)
        self.spectator = Spectator(eval_venv, enabled=request.on_policy)
        self.overlap_evaluation = overlap_evaluation
        self.evaluating: Evaluation | None = None
        """The evaluation under way beside the rollout or the update (PPO), if any."""
        self._busy_s = 0.0  # the trainer's seconds on it before it went beside the update
        self.episode_steps: list[int] = []
        self.longest_seen = 0  # steps of the longest episode seen so far, finished or not
        self._episodes: list[tuple[float, float]] = []
        self._rows: list[list] = []
        self.sample_in_workers = sample_in_workers
        """PPO with a camera network: the workers draw the training cars' actions
        (:meth:`_sample_rollout`); False, or any other policy: SB3's ``collect_rollouts``,
        the trainer choosing every step's actions."""
        self._sampling_seeded = False
        self._ahead: _Run | None = None
        """``request.lagged_rollout``: the next rollout, under way beside the update."""

    # ------------------------------------------------------------------ step bookkeeping
    def collect(self, info: dict, learner: Learner) -> None:
        trace = info.get("trace")
        if trace is not None:
            self._rows.append(trace)
            if isinstance(trace[1], int) and trace[1] > self.longest_seen:
                self.longest_seen = trace[1]
        frame = info.get("frame")
        if frame is not None:
            learner.hooks.on_frame({**frame, "phase": "training",
                                    "iteration": learner.iteration + 1})  # fmt: skip
        entry = info.get("episode_entry")
        if entry is not None:
            self.episode_steps.append(int(entry.get("steps", 0)))
            self._episodes.append(
                (float(entry.get("total_reward", 0.0)), float(entry.get("progress", 0.0)))
            )
            learner.hooks.on_episode(entry)

    # ------------------------------------------------------------------ the protocol
    def gather(self, learner: Learner) -> Experience | None:
        self._episodes, self._rows = [], []
        model = learner.model
        t0 = time.monotonic()
        before = model.num_timesteps
        if self.request.on_policy:
            complete, learned_s = self._collect_rollout(learner), None
        else:
            complete, learned_s = self._drive_and_learn(learner), 0.0
        if not complete:
            return None  # an interrupted rollout is not learnt from
        return Experience(
            steps=model.num_timesteps - before,
            episodes=self._episodes,
            rows=self._rows,
            rollout_s=time.monotonic() - t0,
            learned_s=learned_s,
            spare_cores=self._spare_cores(),
            between_minibatches=functools.partial(self._beside_update, learner),
        )

    def _collect_rollout(self, learner: Learner) -> bool:
        """PPO: one rollout into the model's buffer, as SB3's ``learn`` collects it (with
        ``lagged_rollout``, mostly driven already, beside the update before)."""
        model = learner.model
        ahead, self._ahead = self._ahead, None
        n_steps = ahead.n_steps if ahead is not None else self._planned_steps(model.n_envs)
        model.set_rollout_steps(n_steps)
        total, callback = model._setup_learn(
            n_steps * model.n_envs, _StepWatcher(self, learner), reset_num_timesteps=False
        )
        callback.on_training_start(locals(), globals())
        net = export_greedy(model.policy) if self.sample_in_workers else None
        if net is not None or ahead is not None:
            run = ahead or _Run(n_steps, model.policy, net, self._first_seed())
            complete = self._sample_rollout(learner, run)
        else:
            complete = model.collect_rollouts(model.env, callback, model.rollout_buffer,
                                              n_rollout_steps=n_steps)  # fmt: skip
        callback.on_training_end()
        if complete:
            model._update_current_progress_remaining(model.num_timesteps, total)
        complete = bool(complete) and not learner.stop_reason()
        if complete and net is not None and self.request.lagged_rollout:
            self._ahead = self._drive_ahead(learner, net)
        return complete

    def _planned_steps(self, n_envs: int) -> int:
        """Steps per env of the next rollout, from the episodes seen so far."""
        recent = self.episode_steps[-50:]
        guess = max(INITIAL_EPISODE_STEPS, float(self.longest_seen))
        mean_len = float(np.mean(recent)) if recent else guess
        return plan_rollout_steps(self.request.episodes_per_update, mean_len, n_envs)

    def _first_seed(self) -> int | None:
        """The seed of the workers' draws for the run's first chunk; None after it."""
        if self._sampling_seeded:
            return None
        self._sampling_seeded = True
        seed = self.request.seed
        return int(np.random.default_rng().integers(2**31)) if seed is None else seed

    def _sample_rollout(self, learner: Learner, run: _Run) -> bool:
        """PPO with a camera network: the workers drive the rollout, drawing each car's action
        from ``run.net`` (the policy's network in NumPy) :data:`SAMPLE_STEPS` steps a command,
        while the trainer books the chunk before (infos, episodes, the live view) and keeps
        the evaluation going; then ``run.policy``'s values and log-probabilities for the whole
        rollout in a few batches, into the buffer as SB3's ``collect_rollouts`` fills it.
        A rollout driven ahead (``lagged_rollout``) brings the chunks that came in during the
        update, booked first. False: stopped (not learnt from)."""
        model, venv = learner.model, self.venv
        model.policy.set_training_mode(False)
        self.spectator.stop()
        chunks: list[SampledSteps] = []
        stopped = False
        for part in run.received:
            self._book(learner, part)
            chunks.append(part)
        while True:
            # Two chunks under way: each worker drives the next while the trainer takes up
            # this one (and while the other worker ends its own), never waiting for a command.
            while len(run.in_flight) < SAMPLES_AHEAD and run.sent < run.n_steps and not stopped:
                self._send_chunk(learner, run)
            if not run.in_flight:
                break
            self._wait_for_workers(learner)
            part = venv.receive_sample()
            run.in_flight.pop(0)
            self._book(learner, part)
            chunks.append(part)
            self.advance_evaluation(learner)
            stopped = stopped or bool(learner.stop_reason())  # the chunks under way come back
        if stopped:
            return False
        self.rollout_ended(learner)  # the live view's laps go on while the values are computed
        fill_sampled_rollout(model, chunks, run.policy)
        return True

    def _book(self, learner: Learner, part: SampledSteps) -> None:
        """A chunk's infos, episodes and frames, and its steps counted, as SB3 counts them."""
        model = learner.model
        for infos, dones in zip(part.infos, part.dones, strict=True):
            for info in infos:
                self.collect(info, learner)
            model.num_timesteps += self.venv.num_envs
            model._update_info_buffer(infos, dones)

    def _send_chunk(self, learner: Learner, run: _Run, *, beside_update: bool = False) -> None:
        """``run``'s next chunk goes out (the network and the seed with its first). While the
        live view shows a training car, chunks are short, so that its frames come as they are
        driven (a frame every 1/15 s; two long chunks taken up back to back would bring four
        at once, and the view keeps only the newest two). Beside the update the live view
        shows the evaluation or the spare lap: no frames."""
        # The live view shows the evaluation beside the rollout while there is one.
        frames = (not beside_update and learner.hooks.frames_wanted()
                  and self.evaluating is None)  # fmt: skip
        steps = min(WATCHED_CHUNK_STEPS if frames else SAMPLE_STEPS, run.n_steps - run.sent)
        self.venv.want_frames = frames
        self.venv.send_sample(run.net, steps, run.seed)
        run.net = run.seed = None  # the workers keep them
        run.sent += steps
        run.in_flight.append(steps)

    def _drive_ahead(self, learner: Learner, net: dict) -> _Run:
        """``lagged_rollout``: the next rollout starts now, with the policy that drove this one
        (``net``), so that the workers drive it while the trainer updates; its chunks come in
        between the update's minibatches (:meth:`_beside_update`)."""
        model = learner.model
        run = _Run(self._planned_steps(model.n_envs), frozen_copy(model.policy), net, None)
        while len(run.in_flight) < SAMPLES_AHEAD and run.sent < run.n_steps:
            self._send_chunk(learner, run, beside_update=True)
        return run

    def _beside_update(self, learner: Learner) -> None:
        """Between two of the update's minibatches: the evaluation beside it, once it has
        ended, goes back; the chunks of a rollout driven ahead that are in come in and the
        next go out."""
        self.take_evaluation(learner, wait=False)
        run = self._ahead
        if run is None:
            return
        while run.in_flight and self.venv.sample_ready():
            run.received.append(self.venv.receive_sample())
            run.in_flight.pop(0)
        while len(run.in_flight) < SAMPLES_AHEAD and run.sent < run.n_steps:
            self._send_chunk(learner, run, beside_update=True)

    def _wait_for_workers(self, learner: Learner) -> None:
        """Until the training workers' chunk is there: take up the evaluation's steps whenever
        its worker has them, so that it drives on beside the rollout."""
        venv = self.venv
        while not venv.sample_ready():
            evaluation = self.evaluating
            if evaluation is not None and (not evaluation.in_flight or evaluation.ready()):
                self.advance_evaluation(learner)  # its next chunk, or its end
                continue
            watching = evaluation.venv.filenos() if evaluation is not None else []
            select.select(venv.filenos() + watching, [], [], WAIT_S)

    def _drive_and_learn(self, learner: Learner) -> bool:
        """SAC: drive on in chunks (learning after every step) until enough episodes end; its
        updates are counted in the rollout's time."""
        model = learner.model
        target = len(self.episode_steps) + self.request.episodes_per_update
        chunk = max(64, 16 * model.n_envs)
        for _ in range(MAX_SAC_CHUNKS):
            model.learn(total_timesteps=chunk, reset_num_timesteps=False,
                        callback=_StepWatcher(self, learner), progress_bar=False)  # fmt: skip
            if len(self.episode_steps) >= target or learner.stop_reason():
                break
        return not learner.stop_reason()

    def evaluate(self, learner: Learner, iteration: int) -> None:
        """PPO: the evaluation starts now and drives a step beside each step of the next
        rollout (its policy is the one that rollout drives with); whatever is left of it at
        the rollout's end is driven beside the next update, on the :class:`Spectator`'s
        thread, and its outcome goes back when it ends: between two of the update's
        minibatches (:attr:`Experience.between_minibatches`) or here, first, once it ends
        (should that stop the loop, ``iteration`` is not evaluated: the loop ends without
        keeping it, as when the stop comes during the update). SAC (whose policy changes as it
        drives) and ``overlap_evaluation=False``: the whole evaluation, now."""
        if self.take_evaluation(learner, wait=True) and learner.stop_reason():
            return
        self.spectator.stop()
        self.evaluating = Evaluation(self.eval_venv, self.request, iteration,
                                     learner.model.policy)  # fmt: skip
        if self.overlap_evaluation and self.request.on_policy:
            self.venv.want_frames = False  # the evaluation's car is on the live view first
            return
        self.finish_evaluation(learner)
        self.spectator.start(learner, iteration)  # while the iteration is stored and logged

    def rollout_ended(self, learner: Learner) -> None:
        """The rest of the evaluation under way goes beside the update; then, for whoever
        watches, the live view's laps."""
        evaluation = self.evaluating
        if evaluation is not None:
            self._busy_s = evaluation.busy_s
        self.spectator.start(learner, learner.iteration + 1, evaluation)

    def take_evaluation(self, learner: Learner, *, wait: bool) -> bool:
        """Hand back the evaluation driven beside the update once it has ended (``wait``: wait
        for its end; its ``busy_s`` counts that wait). True if one went back."""
        t0 = time.monotonic()
        evaluation = self.spectator.take_evaluation(wait=wait)
        if evaluation is None:
            return False
        evaluation.busy_s = self._busy_s + (time.monotonic() - t0)
        self._evaluated(learner)
        return True

    def _spare_cores(self) -> int:
        """Cores PPO's updates leave to this source: one for an evaluation beside the update
        (its worker, and the trainer's thread that drives it). Every update of the run leaves
        it, whether or not an evaluation runs beside that one, so that a run's arithmetic
        does not depend on timing."""
        return 1 if self.request.on_policy else 0

    def advance_evaluation(self, learner: Learner) -> None:
        """One more step of the evaluation under way, if any, while the rollout's envs step."""
        evaluation = self.evaluating
        if evaluation is None:
            return
        if evaluation.in_flight:
            if not evaluation.ready():
                return  # the workers are still driving: the rollout goes on
            evaluation.receive(learner.hooks)
        if evaluation.finished:
            self._evaluated(learner)
        else:
            self.eval_venv.want_frames = learner.hooks.frames_wanted()
            evaluation.send(learner.model.policy)

    def finish_evaluation(self, learner: Learner, *, until_stop: bool = True) -> None:
        """Drive the evaluation under way, if any, to its end (``until_stop``: or to a stop of
        the loop) and hand back its outcome."""
        evaluation = self.evaluating
        if evaluation is None:
            return
        # The live view shows the evaluation lap too.
        evaluation.drive(learner.model.policy, learner.hooks,
                         want_frames=learner.hooks.frames_wanted,
                         until=learner.stop_reason if until_stop else None)  # fmt: skip
        self._evaluated(learner)

    def _evaluated(self, learner: Learner) -> None:
        evaluation, self.evaluating = self.evaluating, None
        learner.evaluated(evaluation.iteration, evaluation.outcome, evaluation.busy_s)

    def finish(self, learner: Learner) -> None:
        """The last evaluation, if the loop stopped before the rollout or the update it ran
        beside ended: to its end (a few seconds at most), since its iteration was learnt and
        is kept; the chunks of a rollout driven ahead that are under way come back (the
        workers then close at once)."""
        self.take_evaluation(learner, wait=True)
        self.finish_evaluation(learner, until_stop=False)
        ahead, self._ahead = self._ahead, None
        for _ in ahead.in_flight if ahead is not None else ():
            self.venv.receive_sample()  # a rollout driven ahead that nobody learns from

    def close(self) -> None:
        self.spectator.stop(abort=True)
        for venv in (self.venv, self.eval_venv):
            try:
                venv.close()
            except Exception:  # noqa: BLE001 - closing must not hide the real error
                pass
