"""Head-to-head races of stored models, run here: in this process for the command line
(:func:`race_models`), or as a race job on an evaluation worker (:func:`run_race_job`).

The cars come from the store (trained here or imported, AWS-era models included): a league
entry from its frozen copy and the metadata recorded when it was entered (deleting or
retraining the model changes nothing there), any other entry from its model's best checkpoint
when the race starts. A car that cannot race (no checkpoint, a file missing from the store,
weights that do not load, a deleted model, a withdrawn racer) keeps its grid slot and is out
from the start with the reason; the race goes on. The track comes from the catalogue (an
imported one synced from the database first)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import replace

from django.utils import timezone

from racing.conditions import Conditions
from racing.headtohead import Racer
from racing.race import RaceConfig
from racing.simtrace import SPEED_MULTIPLIER_COLUMN, with_column
from racing.track import Track
from training import live, services
from training.interchange.layout import RaceKeys, evaluation_stamp
from training.models import RaceJob, RacingModel
from training.rl.algorithms import set_torch_threads
from training.rl.checkpoints import CheckpointError, load_checkpoint
from training.rl.evaluation import sb3_policy
from training.rl.metadata import MetadataError, ModelMetadata
from training.rl.race import RaceEntry, RaceReport, RaceSettings, run_race
from training.services import model_metadata, track_catalog, tracks_sync_for
from training.services.challenges import CHALLENGE
from training.services.race_control import RaceSpeeds
from training.services.races import race_conditions_of
from training.storage import StoreError
from training.store import get_store, keys_for
from training.worker.common import Heartbeat, StopFlag, csv_text, fail_with
from training.worker.racelive import FRAME_S, RaceBroadcast

CLEAR_ERRORS = (StoreError,)


def race_entry(model: RacingModel) -> RaceEntry:
    """The model's car: its sensors, action space and best checkpoint's policy
    (``unavailable`` when its weights cannot be had)."""
    return _entry(model.pk, model.name, services.model_metadata(model),
                  keys_for(model.pk).best, trained=model.has_checkpoint)  # fmt: skip


def _entry(key: int, name: str, meta: ModelMetadata | None, checkpoint: str, *,
           metadata: dict | None = None, trained: bool = True) -> RaceEntry:  # fmt: skip
    entry = RaceEntry(key=key, name=name)
    try:
        meta = meta or ModelMetadata.from_json(metadata)
    except MetadataError as exc:
        entry.unavailable = f"its model_metadata.json is not valid: {exc}"
        return entry
    entry.racer = Racer(sensors=tuple(meta.sensor), action_space=meta.actions.to_metadata(),
                        name=name)  # fmt: skip
    entry.metadata = meta.to_json()
    if not trained:
        entry.unavailable = "it has no trained checkpoint"
        return entry
    try:
        entry.policy = sb3_policy(load_checkpoint(get_store().get_bytes(checkpoint), meta))
    except (CheckpointError, StoreError) as exc:
        entry.unavailable = f"its checkpoint cannot be loaded: {exc}"
    return entry


def job_entries(job: RaceJob) -> list[RaceEntry]:
    """The cars of a race job, in entry order."""
    models = {m.pk: m for m in RacingModel.objects.filter(pk__in=job.model_ids)}
    entries = []
    for item in job.entries:
        key, name = int(item["model"]), str(item.get("name", ""))
        if item.get("withdrawn"):
            entries.append(RaceEntry(key=key, name=name, unavailable=str(item["withdrawn"])))
        elif item.get("checkpoint") and item.get("metadata"):
            entries.append(_entry(key, name, None, item["checkpoint"], metadata=item["metadata"]))
        elif key in models:
            entries.append(race_entry(models[key]))
        else:
            entries.append(RaceEntry(key=key, name=name, unavailable="its model was deleted"))
    return entries


def race_track(track_id: str, direction: str) -> Track:
    """The track in its driving direction (an imported one synced to this machine first)."""
    tracks_sync_for([track_id])
    return track_catalog().load(track_id).in_direction(direction)


def race_models(
    models: Sequence[RacingModel],
    *,
    track_id: str,
    direction: str,
    settings: RaceSettings,
    race: RaceConfig | None = None,
    title: str = "",
    **hooks,
) -> RaceReport:
    """Race ``models`` (2-4, in entry order) here; ``hooks`` go to :func:`run_race`."""
    set_torch_threads(1)  # one observation per car and step: a second thread only waits
    entries = [race_entry(model) for model in models]
    track = race_track(track_id, direction)
    return run_race(entries, track, settings, race=race, title=title, **hooks)


def race_world(job: RaceJob) -> Conditions | None:
    """The outside-world conditions of a race job's cameras (a league event's draw), or None:
    the clean world."""
    return Conditions.from_dict(job.conditions) if job.conditions else None


def run_race_job(race_id: int, worker: str = "", *, paced: bool = False, task_id: str = "") -> str:
    """Claim and run race job ``race_id``: the results on the job, the broadcast MP4 and each
    car's sim-trace in the store, live frames and timing to the race's group while anyone
    watches (``paced``: at real time, for a live race day). ``task_id``: the Celery task, a
    token of the fair order (the fairest queued race runs, see
    :mod:`training.services.job_queue`); "" claims ``race_id`` itself. Returns
    ``"completed"``, ``"failed"``, ``"skipped"`` or ``"superseded"``."""
    job = services.job_claim(job_model=RaceJob, job_id=race_id, worker=worker, task_id=task_id)
    if job is None:
        return "skipped"
    set_torch_threads(1)
    groups = [
        live.job_group("race", job.pk),
        *([job.broadcast_group] if job.broadcast_group else []),
    ]
    # ``paced`` was asked for the task's own race; a token may have brought another one.
    broadcast = RaceBroadcast(groups, paced=(paced and job.pk == race_id) or job.paced)
    on_frame = broadcast.frame
    if watched_at_real_time(job) and not broadcast.paced:
        on_frame = WatchedPace(lambda: live.is_watched(groups[0]), broadcast.frame).frame
    store, keys = get_store(), RaceKeys(job.pk)
    try:
        entries = job_entries(job)
        track = race_track(job.track_id, job.direction)
        race, settings = race_conditions_of(job)
        services.job_begin(job=job)
        speeds = RaceSpeeds(job.pk, len(entries))
        live_speed_control(entries, speeds)
        with Heartbeat(RaceJob, job.pk):
            report = run_race(entries, track, settings, race=race, title=job.title,
                              should_stop=StopFlag(job), on_frame=on_frame,
                              conditions=race_world(job))  # fmt: skip
        stamp = evaluation_stamp(job.started_at or timezone.now())
        metadata = {entry.key: entry.metadata for entry in entries}
        index_of = {entry.key: i for i, entry in enumerate(entries)}
        for car in report.cars:
            store.put_bytes(keys.car_simtrace(int(car.key), stamp),
                            speed_trace(csv_text(car.rows), speeds, index_of[car.key]).encode(),
                            "text/csv")  # fmt: skip
            if metadata.get(car.key):
                data = json.dumps(metadata[car.key]).encode()
                store.put_bytes(keys.car_metadata(int(car.key)), data, "application/json")
        if report.video_mp4:
            store.put_bytes(keys.video, report.video_mp4, "video/mp4")
    except Exception as exc:  # noqa: BLE001 - every failure ends the job with a message
        return fail_with(job, exc, what="race", clear=CLEAR_ERRORS)
    finally:
        broadcast.close()
    completed = services.job_complete(job=job, results=report.to_json(),
                                      has_video=bool(report.video_mp4),
                                      race_time_s=report.race_time_s)  # fmt: skip
    if completed:
        message = {"type": "job.status", "status": "COMPLETED", "results": report.to_json()}
        live.send(live.job_group("race", job.pk), message)
    return "completed" if completed else "superseded"


def watched_at_real_time(job: RaceJob) -> bool:
    """A racer's race from the Races page runs at real time while its racer watches it live
    (and at full speed otherwise: the slot is free sooner). A race day's races (``paced``)
    always run at real time. The race itself (its results, replay and sim-traces) is the
    same either way: pacing only waits between steps."""
    return job.purpose == CHALLENGE and not job.paced


class WatchedPace:
    """An ``on_frame`` that holds the race to real time (one frame of race clock,
    :data:`~training.worker.racelive.FRAME_S`, per FRAME_S of wall time) while ``watched()``
    says someone watches, asked at most every ``check_s`` seconds of wall time, then hands the
    frame on to ``send``. Behind, it never races to catch up; unwatched, it never waits."""

    def __init__(self, watched: Callable[[], bool], send: Callable[[object, dict], None], *,
                 check_s: float = 1.0, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:  # fmt: skip
        self.watched, self.send, self.check_s = watched, send, check_s
        self.clock, self.sleep = clock, sleep
        self._checked: float | None = None
        self._watching = False
        self._next: float | None = None
        self.waited_s = 0.0

    def frame(self, rgb: object, header: dict) -> None:
        now = self.clock()
        if self._checked is None or now - self._checked >= self.check_s:
            self._checked, self._watching = now, bool(self.watched())
        if not self._watching:
            self._next = None
        else:
            self._next = now if self._next is None else self._next + FRAME_S
            wait = self._next - now
            if wait > 0:
                self.sleep(wait)
                self.waited_s += wait
            else:
                self._next = now  # behind: never race to catch up
        self.send(rgb, header)


def live_speed_control(entries: list[RaceEntry], speeds: RaceSpeeds) -> None:
    """Give each car the race's live speed control: its racer reads its multiplier once per
    step it drives (:class:`~training.services.race_control.RaceSpeeds`: from a copy that one
    Redis ``MGET`` refreshes at most every 0.2 s of race clock)."""
    for index, entry in enumerate(entries):
        if entry.racer is not None:
            entry.racer = replace(entry.racer, speed=speeds.reader(index))


def speed_trace(csv: str, speeds: RaceSpeeds, index: int) -> str:
    """A car's sim-trace with the multiplier of each step it drove as a last column."""
    try:
        return with_column(csv, SPEED_MULTIPLIER_COLUMN, speeds.log[index])
    except ValueError:  # rows dropped as malformed: the trace as it is, never misaligned
        return csv


__all__ = ["job_entries", "model_metadata", "race_entry", "race_models", "run_race_job"]
