"""Streamed experience (issue 14): PPO fed by simulation workers that own their episodes
(:mod:`training.rl.simulation`), here or on other machines, through Redis streams
(:mod:`training.rollout.streams`).

One iteration: the trainer publishes policy version v with ``episodes_per_update`` episode
tickets and ``eval_episodes`` evaluation tickets; workers drive the training episodes with v and
stream them back; once the quota is in, :meth:`StreamedExperience.gather` builds PPO's rollout
buffer from those episodes (GAE here, with the values the workers computed and, for an episode
cut by the time limit, the bootstrap value of its last observation); the loop updates and
:meth:`StreamedExperience.evaluate` publishes v + 1. Workers that find no training ticket left
run v's evaluation laps meanwhile, so evaluation overlaps the update and the trainer never
waits for one: iteration i's evaluation goes back to the loop when v_i's laps are in, usually
during the next rollout.

Only experience of the current version is learnt from, so PPO stays exactly on-policy (its
log-probabilities and values are the current policy's). DeepRacer instead lets the rollout of
v + 1 start on v while the update runs, learning one version late through PPO's clipped ratio;
we keep the simulation busy with evaluation laps instead of stale training episodes. Unclaimed
evaluation laps of v are withdrawn when v + 1 is published: a short update may evaluate v on
fewer laps than asked (its row says how many, one progress per lap).

A worker that dies mid-episode (its heartbeat lapses, or its local process exits) has its
claimed tickets put back, so another worker drives them, and it is started again; an episode is
counted once, by ticket, on its last chunk. A trainer that dies leaves its last checkpoint; its
workers end when its heartbeat stops, and the job resumes from the checkpoint with a new session.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from training.rollout.buffers import rollout_buffer
from training.rollout.experience import (
    EvaluationOutcome,
    Experience,
    ExperienceRequest,
    Hooks,
    Learner,
)
from training.rollout.streams import (
    Chunk,
    Session,
    StreamError,
    finite,
    read_chunk,
    read_frame,
)
from training.rollout.vecenv import RolloutError
from training.sandbox import RewardFunctionError
from training.sandbox.errors import RewardError

log = logging.getLogger(__name__)
LaunchWorker = Callable[..., object]
"""Starts one simulation worker (:func:`training.rl.simulation.serve_simulation`) with the given
keyword arguments: a local process (its ``poll``, ``kill`` and ``wait`` are used) or a task on
the ``simulation`` queue of another machine."""
START_TIMEOUT_S = 120.0
"""No simulation worker alive this long after the start: a clear error."""
MAX_RESTARTS = 3
"""Times each worker slot is started again after its worker died."""
CHECK_WORKERS_S = 0.5


@dataclass
class _Slot:
    """One simulation worker slot: the worker now serving it and its history."""

    index: int
    worker: str = ""
    process: object | None = None
    launched_at: float = 0.0
    seen_alive: bool = False
    restarts: int = 0
    dead: bool = False


@dataclass
class _Pending:
    """A version whose evaluation laps are still being driven."""

    version: int
    expected: int
    laps: dict[str, dict] = field(default_factory=dict)

    def complete(self) -> bool:
        return len(self.laps) >= self.expected


def worker_count(workers: int, spec) -> int:
    """Simulation workers a run starts: the backend's, and at least one per track of a
    multi-track run (each worker drives its own track, as DeepRacer-for-Cloud's do), so that
    no track is left undriven."""
    return max(1, int(workers), len(spec.track_list()))


class StreamedExperience:
    """An :class:`~training.rollout.experience.ExperienceSource` of simulation workers (see the
    module's docstring). ``env`` is a local env for the spaces only: it is never stepped."""

    def __init__(self, request: ExperienceRequest, env: VecEnv, *, redis_url: str,
                 workers: int, launch: LaunchWorker, prefix: str = "") -> None:  # fmt: skip
        if not isinstance(env.observation_space, spaces.Box):
            raise RolloutError("streamed training needs a camera-only observation")
        self.request, self.env = request, env
        self.redis_url, self.prefix, self.launch = redis_url, prefix, launch
        self.obs_shape = tuple(env.observation_space.shape)
        act = env.action_space
        self.action_dim = 0 if isinstance(act, spaces.Discrete) else int(np.prod(act.shape))
        self.started = time.monotonic()
        self.episodes_total = 0
        self.deaths = 0
        self.requeued = 0
        self.session = Session(redis_url, prefix, uuid.uuid4().hex)
        self.session.create()
        self.session.r.set(self.session.keys.trainer, 1, ex=30)
        self.slots = [_Slot(i) for i in range(worker_count(workers, request.spec))]
        self.pending: deque[_Pending] = deque()
        self.counted: dict[str, list[Chunk]] = {}
        self.counted_tickets: list[str] = []  # every episode counted, by ticket, in order
        self._partial: dict[str, list[Chunk]] = {}
        self._rows: list[list] = []
        self._episodes: list[tuple[float, float]] = []
        self._checked = 0.0
        self._hooks: Hooks | None = None
        self._started = False
        self._relay_stop = threading.Event()
        self._relay = threading.Thread(target=self._relay_frames, name="frames", daemon=True)

    # ---------------------------------------------------------------- the protocol
    def gather(self, learner: Learner) -> Experience | None:
        """The quota of episodes of the current version, in the order they finished, in the
        model's rollout buffer; None if stopped. The first call publishes version 0 and
        starts the workers."""
        if not self._started:
            self._start(learner)
        version, quota = learner.iteration, self.request.episodes_per_update
        t0 = time.monotonic()
        self.counted, self._partial, self._rows, self._episodes = {}, {}, [], []
        while len(self.counted) < quota:
            if learner.stop_reason():
                return None
            for entry_id, msg in self.session.read("trainer", block_ms=200):
                self.session.ack(entry_id)
                self._take(msg, version, quota)
            self._hand_back(learner)
            self.check_workers(version)  # after the stream: a worker's last words come first
        model = learner.model
        model.rollout_buffer = rollout_buffer(model, list(self.counted.values()))
        steps = model.rollout_buffer.buffer_size
        model.num_timesteps += steps
        # No cores left to the workers during the update: they drive on through it, as they
        # would on machines of their own.
        return Experience(steps=steps, episodes=self._episodes, rows=self._rows,
                          rollout_s=time.monotonic() - t0)  # fmt: skip

    def evaluate(self, learner: Learner, iteration: int) -> None:
        """Publish the new version with its evaluation laps; the last one's unclaimed laps are
        withdrawn."""
        self._publish(learner, iteration)
        dropped = self.session.withdraw(iteration - 1)
        for row in self.pending:
            if row.version == iteration - 1:
                row.expected -= dropped
        self.pending.append(_Pending(iteration, expected=self.request.eval_episodes))
        self._hand_back(learner)

    def finish(self, learner: Learner) -> None:
        self._hand_back(learner, final=True)

    def _start(self, learner: Learner) -> None:
        self._started, self._hooks = True, learner.hooks
        self._publish(learner, 0)
        for slot in self.slots:
            self._launch(slot)
        self._relay.start()

    # ---------------------------------------------------------------- workers
    def _launch(self, slot: _Slot) -> None:
        req = self.request
        slot.worker = f"w{slot.index}-{uuid.uuid4().hex[:8]}"
        slot.seen_alive, slot.launched_at = False, time.monotonic()
        slot.process = self.launch(
            redis_url=self.redis_url, prefix=self.prefix, session=self.session.keys.session,
            worker=slot.worker,
            # Multi-track: each worker its own track, as DeepRacer-for-Cloud's workers.
            spec=req.spec.for_env(slot.index).to_json(),
            eval_spec=req.eval_spec.for_env(slot.index).to_json(),
            reward_source=req.reward_source, algorithm=req.algorithm, network=req.network,
            hyperparameters=dict(req.hyperparameters),
            seed=req.seed + 1000 * (slot.index + 1) + 100_000 * slot.restarts,
        )  # fmt: skip

    def _exited(self, slot: _Slot) -> bool:
        poll = getattr(slot.process, "poll", None)
        return poll is not None and poll() is not None

    def check_workers(self, version: int) -> None:
        """Requeue the tickets of dead workers, start them again; fail when none can run."""
        now = time.monotonic()
        if now - self._checked < CHECK_WORKERS_S:
            return
        self._checked = now
        for slot in self.slots:
            if slot.dead:
                continue
            alive = self.session.alive(slot.worker) and not self._exited(slot)
            if alive:
                slot.seen_alive = True
                continue
            if not slot.seen_alive and not self._exited(slot):
                continue  # still starting
            self._worker_died(slot, version)
        if all(s.dead for s in self.slots):
            raise RolloutError("every simulation worker stopped; see the worker logs")
        if not any(s.seen_alive for s in self.slots) and now - self.started > START_TIMEOUT_S:
            raise RolloutError(
                f"no simulation worker started within {START_TIMEOUT_S:.0f} s: start one with "
                "`celery -A console worker -Q simulation`"
            )

    def _worker_died(self, slot: _Slot, version: int) -> None:
        self.deaths += 1
        self.session.revoke(slot.worker)  # should it still run, it stops and gives back
        self.session.r.delete(self.session.keys.alive(slot.worker))
        requeued, lost = self.session.requeue(slot.worker, set(self.counted), version)
        self.requeued += requeued
        for text in lost:
            lap_version = int(text.split(":")[1])
            for row in self.pending:
                if row.version == lap_version:
                    row.expected -= 1
        log.warning("simulation worker %s died; %d episode(s) go to another worker",
                    slot.worker, requeued)  # fmt: skip
        if hasattr(slot.process, "kill") and not self._exited(slot):
            _kill(slot.process)  # a local worker that hangs
        if slot.restarts >= MAX_RESTARTS:
            slot.dead = True
            return
        slot.restarts += 1
        self._launch(slot)

    # ---------------------------------------------------------------- frames
    def _relay_frames(self) -> None:
        """Live frames from the watched worker to the hooks, and the trainer's heartbeat, on a
        thread of its own: video goes on while the trainer updates."""
        s = Session(self.redis_url, self.prefix, self.session.keys.session)
        last_id, beat = b"$", 0.0
        hooks = self._hooks
        try:
            while not self._relay_stop.is_set():
                try:
                    now = time.monotonic()
                    watched = hooks is not None and hooks.frames_wanted()
                    if now - beat >= 1.0:
                        beat = now
                        s.r.set(s.keys.trainer, 1, ex=30)
                        s.set_watch(self._frame_worker() if watched else None)
                    for entry_id, msg in s.read_frames(last_id, block_ms=250):
                        last_id = entry_id
                        frame = read_frame(msg)
                        if watched and frame is not None:
                            hooks.on_frame(frame)
                except Exception:  # noqa: BLE001 - video is best effort; the beat goes on
                    log.warning("the frame relay failed; retrying", exc_info=True)
                    self._relay_stop.wait(1.0)
        finally:
            s.close()

    def _frame_worker(self) -> str | None:
        for slot in self.slots:
            if slot.seen_alive and not slot.dead:
                return slot.worker
        return None

    # ---------------------------------------------------------------- the streams
    def _take(self, msg: dict | StreamError, version: int, quota: int) -> None:
        if isinstance(msg, StreamError):
            raise RolloutError(str(msg))
        kind = msg["kind"]
        if kind == "error":
            raise _worker_error(msg)
        if kind == "eval":
            self._take_lap(msg)
        elif kind == "chunk":
            chunk = read_chunk(msg, self.obs_shape, self.action_dim)
            if chunk.version != version or chunk.ticket in self.counted:
                self._partial.pop(chunk.attempt, None)
                return  # another version's, or a ticket already counted: never twice
            parts = self._partial.setdefault(chunk.attempt, [])
            if chunk.seq != len(parts):
                self._partial.pop(chunk.attempt, None)  # a gap: the ticket is driven again
                return
            parts.append(chunk)
            if chunk.last and len(self.counted) < quota:
                self.counted[chunk.ticket] = self._partial.pop(chunk.attempt)
                self.counted_tickets.append(chunk.ticket)
                self._count(parts)

    def _count(self, chunks: list[Chunk]) -> None:
        """Bookkeeping of a counted episode: its trace rows and metrics entry."""
        self.episodes_total += 1
        for chunk in chunks:
            for info in chunk.infos:
                trace = info.get("trace")
                if isinstance(trace, list):
                    self._rows.append(trace)
                entry = info.get("episode_entry")
                if isinstance(entry, dict):
                    self._episodes.append(
                        (float(entry.get("total_reward", 0.0)), float(entry.get("progress", 0.0)))
                    )
                    if self._hooks is not None:
                        self._hooks.on_episode(entry)

    def _take_lap(self, msg: dict) -> None:
        for row in self.pending:
            if row.version == msg.get("version"):
                ticket = str(msg.get("ticket", ""))[:64]
                if ticket not in row.laps:
                    row.laps[ticket] = msg
                return

    def _hand_back(self, learner: Learner, final: bool = False) -> None:
        """Evaluations whose laps are all in (all of them when ``final``), in order."""
        while self.pending and (final or self.pending[0].complete()):
            row = self.pending.popleft()
            laps = sorted(row.laps.values(), key=lambda m: str(m.get("ticket")))
            outcome = EvaluationOutcome(
                progress=[finite(m.get("progress")) for m in laps],
                statuses=[str(m.get("status", ""))[:32] for m in laps],
                lap_times=[[finite(t) for t in m.get("lap_times", [])][:100] for m in laps],
                rewards=[finite(m.get("reward")) for m in laps],
            )
            learner.evaluated(row.version, outcome, sum(finite(m.get("wall_s")) for m in laps))

    def _publish(self, learner: Learner, version: int) -> None:
        state = learner.model.policy.state_dict()
        weights = {k: v.detach().cpu().numpy() for k, v in state.items()}
        evals = [{"start_progress": p} for p in self.request.eval_starts()]
        self.session.publish_policy(version, weights, episodes=self.request.episodes_per_update,
                                    evals=evals if version > 0 else [])  # fmt: skip

    def close(self) -> None:
        try:
            self.session.stop()
        except Exception:  # noqa: BLE001 - closing must not hide the real error
            log.warning("could not tell the simulation workers to stop", exc_info=True)
        self._relay_stop.set()
        if self._relay.is_alive():
            self._relay.join(timeout=5)
        for slot in self.slots:
            if slot.process is not None and hasattr(slot.process, "wait"):
                try:
                    slot.process.wait(timeout=15)
                except Exception:  # noqa: BLE001 - a worker that does not end is killed
                    _kill(slot.process)
        try:
            self.env.close()
        except Exception:  # noqa: BLE001
            pass
        try:
            self.session.cleanup()
        finally:
            self.session.close()


def _worker_error(msg: dict) -> Exception:
    """The error a worker reported, as the lockstep path raises it: a reward function's error
    with its line (:class:`RewardFunctionError`), anything else in the worker's words."""
    if isinstance(msg.get("reward_error"), dict):
        step = msg.get("step")
        return RewardFunctionError(RewardError.from_dict(msg["reward_error"]),
                                   step if type(step) is int else None)  # fmt: skip
    text = msg.get("message")
    return RolloutError(str(text)[:2000] if text else "a simulation worker failed")


def _kill(process) -> None:
    try:
        process.kill()
        process.wait(timeout=10)
    except Exception:  # noqa: BLE001 - already gone
        pass
