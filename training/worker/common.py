"""What training and evaluation jobs share on the worker: heartbeats, the env spec of a model,
sim-trace CSV, the stop flag, and where rollouts run."""

from __future__ import annotations

import logging
import threading
import time

from django.conf import settings
from django.db import connection

from racing.race import RaceConfig, RaceType
from racing.simtrace import SIMTRACE_COLUMNS, TraceRow
from training import dispatch
from training.models import RacingModel
from training.rl.simulation import launch_local, serve_simulation
from training.rollout.backends import LocalRollouts, RolloutBackend, StreamRollouts
from training.rollout.envs import EnvSpec
from training.sandbox import RewardFunctionError
from training.services import (
    job_fail,
    job_heartbeat,
    job_stop_requested,
    track_hashes,
    tracks_sync_for,
)
from training.services.racing import race_config
from training.storage import StoreError

log = logging.getLogger(__name__)
STOP_POLL_S = 1.0
"""How often a running job reads its stop flag from the database, seconds."""
SIMULATE_EPISODES = "training.tasks.simulate_episodes"
"""The ``simulation`` queue's task of a simulation worker that owns its episodes."""
HEARTBEAT_S = 15.0
"""How often a running job stamps its heartbeat, seconds (the reaper waits 300 s)."""


class Heartbeat:
    """Stamps the job's heartbeat every ``every`` seconds from a thread of its own while a job
    runs, however long one policy update takes. If the worker process dies, the stamps stop
    and the orphan reaper (:func:`training.services.jobs_reap_orphans`) fails the job."""

    def __init__(self, job_model, job_id: int, every: float = HEARTBEAT_S) -> None:
        self._job_model, self._job_id = job_model, job_id
        self._every = every
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"heartbeat-{job_id}", daemon=True)

    def _run(self) -> None:
        try:
            while not self._stop.wait(self._every):
                try:
                    job_heartbeat(job_model=self._job_model, job_id=self._job_id)
                except Exception:  # noqa: BLE001 - a missed beat is retried on the next one
                    log.warning("could not record a heartbeat", exc_info=True)
        finally:
            connection.close()

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


class StopFlag:
    """``stop()`` answers whether the job's owner asked it to stop, reading the database at
    most every ``STOP_POLL_S`` seconds (it is polled on every simulation step)."""

    def __init__(self, job) -> None:
        self.job = job
        self._checked = 0.0
        self._stop = False

    def __call__(self) -> bool:
        now = time.monotonic()
        if not self._stop and now - self._checked >= STOP_POLL_S:
            self._checked = now
            self._stop = job_stop_requested(job=self.job)
        return self._stop


def env_spec(
    model: RacingModel,
    *,
    track_id: str | None = None,
    direction: str | None = None,
    race: RaceConfig | None = None,
    conditions: dict | None = None,
    conditions_seed: int | None = None,
) -> EnvSpec:
    """The simulator a job of ``model`` drives: its own tracks (all of them for a model that
    trains on several) and race, or the track and race given; in the clean world unless
    ``conditions`` are given (a training job passes the model's outside-world setting, a league
    event's evaluation the event's, with its ``conditions_seed``). Imported tracks are written into
    this machine's folder first (:func:`~training.services.tracks_sync_for`): a worker may share no
    disk with the web that took the upload."""
    if race is None:
        race = race_config(model.race_type, model.race_config)
    own = track_id is None and direction is None
    tracks = tuple(model.training_tracks) if own and model.extra_tracks else ()
    driven = [track_id or model.track_id, *(t for t, _ in tracks)]
    tracks_sync_for(driven)
    return EnvSpec(
        track=track_id or model.track_id,
        track_dirs=(str(settings.RACECRAFT_TRACKS_DIR),),
        direction=direction or model.direction,
        action_space=model.action_space,
        sensors=tuple(model.sensors),
        race=race.to_dict() if race.race_type is not RaceType.TIME_TRIAL else {},
        tracks=tracks,
        track_hashes=track_hashes(driven),
        conditions=dict(conditions or {}),
        conditions_seed=conditions_seed if conditions else None,
    )


def rollout_backend() -> RolloutBackend:
    """Where a training job's experience comes from (:mod:`training.rollout.backends`).

    ``RACECRAFT_REMOTE_ROLLOUT_SLOTS`` > 0: that many simulation workers on the ``simulation``
    queue (other machines), streaming whole episodes through Redis. Else
    ``RACECRAFT_SIMULATION``: ``"streams"``, two simulation workers as processes of this machine;
    ``"lockstep"`` (the default), the trainer steps sandboxed envs of this machine."""
    slots = int(settings.RACECRAFT_REMOTE_ROLLOUT_SLOTS)
    if slots > 0:
        return StreamRollouts(redis_url=settings.REDIS_URL, workers=slots,
                              launch=send_simulation,
                              prefix=settings.REDIS_PREFIX or "")  # fmt: skip
    if settings.RACECRAFT_SIMULATION == "streams":
        return StreamRollouts(redis_url=settings.REDIS_URL, workers=2, launch=launch_local,
                              prefix=settings.REDIS_PREFIX or "")  # fmt: skip
    return LocalRollouts()


MACHINE_LOCAL = ("redis_url", "prefix")
"""What a simulation message never carries: the sender's Redis address and key prefix (each
machine uses its own ``REDIS_URL`` and ``REDIS_PREFIX``; a password stays out of the queue)."""


def send_simulation(**kwargs) -> str:
    """Queue a streamed simulation worker on the ``simulation`` queue (any machine): the
    message names the tracks by id and content (``track_hashes``), never this machine's
    folder or Redis address; :func:`simulate_here` fills in the worker's own."""
    for key in MACHINE_LOCAL:
        kwargs.pop(key, None)
    for key in ("spec", "eval_spec"):
        if isinstance(kwargs.get(key), dict):
            kwargs[key] = {k: v for k, v in kwargs[key].items() if k != "track_dirs"}
    return dispatch.send(SIMULATE_EPISODES, **kwargs)


def simulate_here(**kwargs) -> str:
    """A streamed simulation worker for a trainer on another machine (the ``simulation``
    queue's task): the imported tracks from the database into this machine's folder, the
    trainer's specs pointed at that folder, and this machine's Redis (never a path or an
    address of the trainer's machine)."""
    here = [str(settings.RACECRAFT_TRACKS_DIR)]
    driven: list[str] = []
    for key in ("spec", "eval_spec"):
        if isinstance(kwargs.get(key), dict):
            kwargs[key] = {**kwargs[key], "track_dirs": here}
            driven += [str(track) for track, _ in EnvSpec.from_json(kwargs[key]).track_list()]
    kwargs.update(redis_url=settings.REDIS_URL, prefix=settings.REDIS_PREFIX or "")
    tracks_sync_for(driven)
    return serve_simulation(**kwargs)


def csv_text(rows: list[list]) -> str:
    """A sim-trace CSV (DeepRacer's 19 columns) from rows a worker reported; a malformed row
    is dropped, never trusted."""
    lines = [",".join(SIMTRACE_COLUMNS)]
    for row in rows:
        try:
            lines.append(TraceRow(*row).format())
        except (TypeError, ValueError):
            continue
    return "\n".join(lines) + "\n"


def fail_with(job, exc: Exception, *, what: str, clear: tuple[type[Exception], ...]) -> str:
    """Fail ``job`` with ``exc``: errors of the ``clear`` types already speak to the user;
    anything else is logged with its traceback and named. Returns ``"failed"``."""
    if isinstance(exc, RewardFunctionError):
        line = f" (line {exc.error.line})" if exc.error.line else ""
        message = f"the reward function failed during training{line}: {exc.error.message}"
    elif isinstance(exc, StoreError):
        log.error("%s job %s failed", what, job.pk, exc_info=exc)  # the whole key and server
        message = f"{what} failed: {exc.public_message()}"
    elif isinstance(exc, clear):
        message = str(exc)
    else:
        log.error("%s job %s failed", what, job.pk, exc_info=exc)
        message = f"{what} failed: {type(exc).__name__}: {exc}"
    job_fail(job=job, error=message)
    return "failed"
