"""Business rules for models and jobs: create, clone, import, delete, train, stop, evaluate.

Every function is keyword-only and raises :class:`ServiceError` (or its subclass
:class:`RewardRejected`, which carries structured reward errors) with a message a user can act
on. Side effects on other processes (Celery) start only after the database commit.
"""

from __future__ import annotations

import json
import logging
import random
from collections.abc import Callable
from dataclasses import dataclass

from django.conf import settings
from django.db import transaction
from django.utils import timezone

from racing.track import TrackError
from racing.tracks import TrackCatalog, UnknownTrackError
from training.interchange.archive import ArchiveError, import_virtual_model
from training.models import (
    ACTIVE_JOB_STATUSES,
    MODEL_NAME_RE,
    Direction,
    EvaluationJob,
    JobStatus,
    RaceType,
    RacingModel,
    TrainingJob,
)
from training.rewards.validation import validate_reward_function
from training.rl.evaluation import EvaluationError, EvaluationSettings
from training.rl.hyperparams import HyperparameterError, parse_hyperparameters
from training.rl.metadata import MetadataError, ModelMetadata, build_metadata
from training.sandbox import MAX_SOURCE_CHARS, RewardError
from training.signals import evaluation_finished
from training.storage import StoreError
from training.store import get_store, keys_for

log = logging.getLogger(__name__)
MIN_MINUTES, MAX_MINUTES = 1, 1440
SUPPORTED_RACE_TYPES = (RaceType.TIME_TRIAL,)


class ServiceError(Exception):
    """A request we refuse; ``field`` names the form field to show it on, when there is one."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field

    @property
    def sentence(self) -> str:
        """The message as a sentence for a page: capitalised."""
        return self.message[:1].upper() + self.message[1:]


class RewardRejected(ServiceError):
    """The reward function failed validation; ``errors`` are DeepRacer-style error dicts."""

    def __init__(self, errors: list[RewardError]) -> None:
        first = errors[0]
        where = f" (line {first.line})" if first.line else ""
        super().__init__(f"{first.message}{where}", field="reward_function")
        self.errors = [e.to_dict() for e in errors]


def catalog() -> TrackCatalog:
    return TrackCatalog([settings.RACECRAFT_TRACKS_DIR])


def _limit(name: str, default: int) -> int:
    return int(getattr(settings, name, default))


# ------------------------------------------------------------------------------ validation
@dataclass(frozen=True)
class ModelSpec:
    """A validated model configuration."""

    metadata: ModelMetadata
    hyperparameters: dict
    track_id: str
    direction: str
    race_type: str
    max_minutes: int


def check_track(track_id: str, direction: str):
    try:
        track = catalog().load(track_id)
    except (UnknownTrackError, TrackError):
        raise ServiceError(f"unknown track {track_id!r}", field="track_id") from None
    if direction not in Direction.values:
        raise ServiceError("direction must be native, ccw or cw", field="direction")
    if not track.closed and direction != Direction.NATIVE:
        raise ServiceError("this track is an open route: it has one direction", field="direction")
    return track.in_direction(direction)


def check_model_spec(
    *,
    track_id: str,
    direction: str,
    race_type: str,
    sensors: list[str],
    action_space: list | dict,
    algorithm: str,
    neural_network: str,
    hyperparameters: dict | None,
    max_minutes: int,
) -> ModelSpec:
    check_track(track_id, direction)
    if race_type not in RaceType.values:
        raise ServiceError(f"unknown race type {race_type!r}", field="race_type")
    if race_type not in SUPPORTED_RACE_TYPES:
        raise ServiceError(
            f"{RaceType(race_type).label} needs obstacles and bot cars, which the simulator "
            "does not have yet; choose Time trial",
            field="race_type",
        )
    try:
        metadata = build_metadata(
            action_space=action_space,
            training_algorithm=algorithm,
            sensor=list(sensors),
            neural_network=neural_network,
        )
    except MetadataError as exc:
        raise ServiceError(str(exc), field=_metadata_field(exc.field)) from None
    try:
        hp = parse_hyperparameters(hyperparameters or {}, algorithm)
    except HyperparameterError as exc:
        raise ServiceError(str(exc), field="hyperparameters") from None
    if not isinstance(max_minutes, int) or not MIN_MINUTES <= max_minutes <= MAX_MINUTES:
        raise ServiceError(
            f"the stop condition is {MIN_MINUTES}-{MAX_MINUTES} minutes", field="max_minutes"
        )
    return ModelSpec(metadata, hp.to_json(), track_id, direction, race_type, max_minutes)


def _metadata_field(field: str) -> str:
    return {
        "training_algorithm": "algorithm",
        "sensor": "sensors",
        "action_space_type": "action_space",
    }.get(field, field)


def check_reward(source: str, track_id: str, direction: str = "native") -> dict:
    """Validate a reward function on the track (static checks, then sandboxed runs)."""
    if not isinstance(source, str) or not source.strip():
        raise ServiceError("write a reward function", field="reward_function")
    if len(source) > MAX_SOURCE_CHARS:
        raise ServiceError(
            f"the reward function is {len(source):,} characters; the limit is {MAX_SOURCE_CHARS:,}",
            field="reward_function",
        )
    track = check_track(track_id, direction)
    result = validate_reward_function(source, track)
    if not result.ok:
        raise RewardRejected(result.errors)
    return {"rewards": result.rewards}


def check_name(owner, name: str, *, exclude: int | None = None) -> None:
    import re

    if not isinstance(name, str) or not re.match(MODEL_NAME_RE, name):
        raise ServiceError("a model name is 1-64 letters, digits or hyphens", field="name")
    taken = RacingModel.objects.filter(owner=owner, name=name)
    if exclude is not None:
        taken = taken.exclude(pk=exclude)
    if taken.exists():
        raise ServiceError(f"you already have a model named {name!r}", field="name")


def check_model_quota(owner) -> None:
    limit = _limit("RACECRAFT_MAX_MODELS_PER_USER", 50)
    if RacingModel.objects.filter(owner=owner).count() >= limit:
        raise ServiceError(f"you have {limit} models, the most allowed; delete one to make room")


# ------------------------------------------------------------------------------ models
def _store_model_files(model: RacingModel) -> None:
    store = get_store()
    keys = keys_for(model.pk)
    store.put_bytes(keys.metadata, model_metadata(model).dumps(), "application/json")
    store.put_bytes(
        keys.hyperparameters,
        json.dumps(model.hyperparameters, indent=2).encode(),
        "application/json",
    )
    store.put_bytes(keys.reward_function, model.reward_function.encode(), "text/x-python")


def model_metadata(model: RacingModel) -> ModelMetadata:
    return build_metadata(
        action_space=model.action_space,
        training_algorithm=model.algorithm,
        sensor=list(model.sensors),
        neural_network=model.neural_network,
    )


def model_create(
    *,
    owner,
    name: str,
    description: str = "",
    track_id: str,
    direction: str = "native",
    race_type: str = RaceType.TIME_TRIAL,
    sensors: list[str] | tuple[str, ...] = ("FRONT_FACING_CAMERA",),
    action_space: list | dict,
    algorithm: str = "clipped_ppo",
    neural_network: str = "RACECRAFT_LEAN_CNN",
    hyperparameters: dict | None = None,
    reward_function: str,
    max_minutes: int = 10,
    seed: int | None = None,
    validate_reward: bool = True,
) -> RacingModel:
    """A new model, validated end to end (its reward function runs in the sandbox first)."""
    check_name(owner, name)
    if len(description) > 255:
        raise ServiceError("the description is at most 255 characters", field="description")
    check_model_quota(owner)
    spec = check_model_spec(
        track_id=track_id, direction=direction, race_type=race_type, sensors=list(sensors),
        action_space=action_space, algorithm=algorithm, neural_network=neural_network,
        hyperparameters=hyperparameters, max_minutes=max_minutes,
    )  # fmt: skip
    if validate_reward:
        check_reward(reward_function, track_id, direction)
    model = RacingModel.objects.create(
        owner=owner,
        name=name,
        description=description,
        track_id=spec.track_id,
        direction=spec.direction,
        race_type=spec.race_type,
        sensors=list(spec.metadata.sensor),
        neural_network=spec.metadata.neural_network,
        action_space_type=spec.metadata.action_space_type,
        action_space=spec.metadata.actions.to_metadata(),
        algorithm=spec.metadata.training_algorithm,
        hyperparameters=spec.hyperparameters,
        reward_function=reward_function,
        max_minutes=spec.max_minutes,
        seed=seed if seed is not None else random.randrange(2**31),
        status=RacingModel.Status.READY,
    )
    _store_model_files(model)
    return model


def model_clone(
    *,
    model: RacingModel,
    owner,
    name: str,
    description: str = "",
    track_id: str | None = None,
    direction: str | None = None,
    reward_function: str | None = None,
    hyperparameters: dict | None = None,
    max_minutes: int | None = None,
    action_space: list | dict | None = None,
    checkpoint: str = "best",
) -> RacingModel:
    """A new model that starts from ``model``'s best (or last) checkpoint. Algorithm, network,
    sensors, action-space type and number of actions stay as they were."""
    _owned(model, owner)
    if not model.has_checkpoint:
        raise ServiceError("this model has no trained checkpoint to start from yet")
    if checkpoint not in ("best", "last"):
        raise ServiceError("clone from the best or the last checkpoint", field="checkpoint")
    new_actions = model.action_space if action_space is None else action_space
    if model.action_space_type == "discrete" and (
        not isinstance(new_actions, list) or len(new_actions) != len(model.action_space)
    ):
        raise ServiceError(
            "a clone keeps the number of actions; you may change their values",
            field="action_space",
        )
    if model.action_space_type == "continuous" and not isinstance(new_actions, dict):
        raise ServiceError("a clone keeps a continuous action space", field="action_space")
    clone = model_create(
        owner=owner,
        name=name,
        description=description,
        track_id=track_id or model.track_id,
        direction=direction or model.direction,
        race_type=model.race_type,
        sensors=list(model.sensors),
        action_space=new_actions,
        algorithm=model.algorithm,
        neural_network=model.neural_network,
        hyperparameters=hyperparameters if hyperparameters is not None else model.hyperparameters,
        reward_function=reward_function if reward_function is not None else model.reward_function,
        max_minutes=max_minutes or model.max_minutes,
        validate_reward=True,
    )
    store = get_store()
    src, dst = keys_for(model.pk), keys_for(clone.pk)
    try:
        data = store.get_bytes(src.best if checkpoint == "best" else src.last)
        store.put_bytes(dst.checkpoint("initial"), data)
        store.put_bytes(dst.best, data)
        store.put_bytes(dst.last, data)
    except StoreError as exc:
        clone_delete_quietly(clone)
        raise ServiceError(f"the parent's checkpoint could not be copied: {exc}") from None
    clone.parent = model
    clone.has_checkpoint = True
    clone.save(update_fields=["parent", "has_checkpoint", "updated_at"])
    return clone


def clone_delete_quietly(model: RacingModel) -> None:
    try:
        get_store().delete_prefix(keys_for(model.pk).prefix)
    except StoreError:
        log.warning("could not clean up the store of model %s", model.pk)
    model.delete()


def model_import(*, owner, name: str, upload, description: str = "") -> RacingModel:
    """A model from a virtual-model archive (as downloaded from Racecraft), validated."""
    check_name(owner, name)
    check_model_quota(owner)
    try:
        imported = import_virtual_model(upload)
    except ArchiveError as exc:
        raise ServiceError(str(exc), field="archive") from None
    meta = imported.metadata
    model = model_create(
        owner=owner,
        name=name,
        description=description,
        track_id=_default_track(),
        sensors=list(meta.sensor),
        action_space=meta.actions.to_metadata(),
        algorithm=meta.training_algorithm,
        neural_network=meta.neural_network,
        hyperparameters=imported.hyperparameters.to_json(),
        reward_function=imported.reward_function,
        max_minutes=10,
        validate_reward=False,
    )
    store, keys = get_store(), keys_for(model.pk)
    for key in (keys.best, keys.last, keys.checkpoint("initial")):
        store.put_bytes(key, imported.checkpoint_bytes)
    model.imported = True
    model.has_checkpoint = True
    model.save(update_fields=["imported", "has_checkpoint", "updated_at"])
    return model


def _default_track() -> str:
    ids = catalog().ids()
    return "racecraft_summit" if "racecraft_summit" in ids else ids[0]


def model_delete(*, model: RacingModel, user) -> None:
    """Delete a model, its jobs and every stored object. Refused while a job runs."""
    _owned(model, user)
    if _active_jobs(model).exists():
        raise ServiceError("stop the model's training or evaluation before deleting it")
    model.status = RacingModel.Status.DELETING
    model.save(update_fields=["status", "updated_at"])
    try:
        get_store().delete_prefix(keys_for(model.pk).prefix)
    except StoreError as exc:
        model.status = RacingModel.Status.ERROR
        model.error = f"deleting the stored files failed: {exc}"
        model.save(update_fields=["status", "error", "updated_at"])
        raise ServiceError(f"the model's files could not be deleted: {exc}") from None
    model.delete()


def _owned(model: RacingModel, user) -> None:
    if model.owner_id != getattr(user, "pk", None):
        raise ServiceError("not found")


def _active_jobs(model: RacingModel):
    return model.training_jobs.filter(status__in=ACTIVE_JOB_STATUSES)


# ------------------------------------------------------------------------------ jobs
def _active_job_count(user) -> int:
    return (
        TrainingJob.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + EvaluationJob.objects.filter(
            model__owner=user, status__in=ACTIVE_JOB_STATUSES, purpose="user"
        ).count()
    )


def _check_job_quota(user) -> None:
    limit = _limit("RACECRAFT_MAX_ACTIVE_JOBS_PER_USER", 2)
    if _active_job_count(user) >= limit:
        raise ServiceError(
            f"you already have {limit} jobs queued or running, the most allowed; wait for one "
            "to finish or stop it"
        )


def _enqueue_after_commit(job, send: Callable[[int], str]) -> None:
    """Queue the Celery task once the job row is committed; if queueing fails, the job is
    marked failed at once instead of waiting forever."""

    def go() -> None:
        try:
            task_id = send(job.pk)
        except Exception as exc:  # noqa: BLE001 - any broker failure
            log.exception("could not queue job %s", job.pk)
            job_fail(job=job, error=f"the job could not be queued: {exc}")
            return
        type(job).objects.filter(pk=job.pk).update(task_id=task_id or "")

    transaction.on_commit(go)


def training_start(*, model: RacingModel, user, enqueue: bool = True) -> TrainingJob:
    """Queue a training job for a model that has not been trained yet. ``enqueue=False``
    leaves the job for the caller to run in its own process (the command line)."""
    _owned(model, user)
    with transaction.atomic():
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if model.is_busy or _active_jobs(model).exists():
            raise ServiceError("this model is busy; wait for its current job to finish")
        if model.training_jobs.filter(status=JobStatus.COMPLETED).exists():
            raise ServiceError("this model has been trained; clone it to train it further")
        _check_job_quota(user)
        job = TrainingJob.objects.create(model=model, max_minutes=model.max_minutes)
        model.status = RacingModel.Status.QUEUED
        model.error = ""
        model.save(update_fields=["status", "error", "updated_at"])
        if enqueue:
            from training.tasks import train_model

            _enqueue_after_commit(job, lambda pk: train_model.delay(pk).id)
    return job


def evaluation_start(
    *,
    model: RacingModel,
    user,
    track_id: str | None = None,
    direction: str | None = None,
    race_type: str = RaceType.TIME_TRIAL,
    laps: int = 3,
    off_track_penalty_s: float = 2.0,
    crash_penalty_s: float = 5.0,
    purpose: str = "user",
    enqueue: bool = True,
) -> EvaluationJob:
    """Queue an evaluation of a trained model (3-5 laps, DeepRacer's penalties);
    ``enqueue=False`` leaves it for the caller to run in its own process."""
    _owned(model, user)
    track_id = track_id or model.track_id
    direction = direction or model.direction
    check_track(track_id, direction)
    if race_type not in SUPPORTED_RACE_TYPES:
        raise ServiceError("only time trials can be evaluated for now", field="race_type")
    try:
        EvaluationSettings(laps=laps, off_track_penalty_s=off_track_penalty_s,
                           crash_penalty_s=crash_penalty_s)  # fmt: skip
    except EvaluationError as exc:
        raise ServiceError(str(exc), field="laps" if "laps" in str(exc) else None) from None
    with transaction.atomic():
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if not model.has_checkpoint:
            raise ServiceError("train this model before evaluating it")
        if (
            _active_jobs(model).exists()
            or model.evaluations.filter(status__in=ACTIVE_JOB_STATUSES).exists()
        ):
            raise ServiceError("this model is busy; wait for its current job to finish")
        if purpose == "user":
            _check_job_quota(user)
        job = EvaluationJob.objects.create(
            model=model, track_id=track_id, direction=direction, race_type=race_type,
            laps=laps, off_track_penalty_s=off_track_penalty_s,
            crash_penalty_s=crash_penalty_s, purpose=purpose,
        )  # fmt: skip
        model.status = RacingModel.Status.EVALUATING
        model.save(update_fields=["status", "updated_at"])
        if enqueue:
            from training.tasks import evaluate_model

            _enqueue_after_commit(job, lambda pk: evaluate_model.delay(pk).id)
    return job


def job_stop(*, job: TrainingJob | EvaluationJob, user) -> TrainingJob | EvaluationJob:
    """Stop a job: a queued one is canceled at once; a running one stops at the next safe
    point and keeps its last checkpoint (cooperative: the worker polls the flag)."""
    _owned(job.model, user)
    with transaction.atomic():
        job = type(job).objects.select_for_update().get(pk=job.pk)
        if job.status == JobStatus.QUEUED:
            job.status = JobStatus.CANCELED
            job.finished_at = timezone.now()
            job.stop_requested = True
            job.save(update_fields=["status", "finished_at", "stop_requested"])
            _settle_model(job.model)
            if isinstance(job, EvaluationJob):
                evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
        elif job.status in (JobStatus.INITIALIZING, JobStatus.IN_PROGRESS):
            job.status = JobStatus.STOPPING
            job.stop_requested = True
            job.save(update_fields=["status", "stop_requested"])
            RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.STOPPING)
        elif job.status != JobStatus.STOPPING:
            raise ServiceError("this job has already finished")
    return job


def _settle_model(model: RacingModel, error: str = "") -> None:
    """After a job ends: READY when a checkpoint exists, ERROR otherwise."""
    model.refresh_from_db()
    model.status = RacingModel.Status.READY if model.has_checkpoint else RacingModel.Status.ERROR
    if error and not model.has_checkpoint:
        model.error = error
    model.save(update_fields=["status", "error", "updated_at"])


def job_fail(*, job: TrainingJob | EvaluationJob, error: str) -> None:
    type(job).objects.filter(pk=job.pk).update(
        status=JobStatus.FAILED, error=error[:2000], finished_at=timezone.now()
    )
    _settle_model(job.model, error)
    if isinstance(job, EvaluationJob):
        evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)


def jobs_reap_orphans(*, stale_after_s: float = 300.0) -> int:
    """Fail active jobs whose worker stopped sending heartbeats (killed, lost, crashed), and
    queued jobs that no worker took within a day. Returns how many were marked."""
    now = timezone.now()
    stale = now - timezone.timedelta(seconds=stale_after_s)
    marked = 0
    for job_model in (TrainingJob, EvaluationJob):
        running = job_model.objects.filter(
            status__in=(JobStatus.INITIALIZING, JobStatus.IN_PROGRESS, JobStatus.STOPPING)
        ).filter(heartbeat_at__lt=stale)
        for job in running:
            job_fail(job=job, error="the worker running this job stopped unexpectedly; the last "
                                    "checkpoint was kept")  # fmt: skip
            marked += 1
        forgotten = job_model.objects.filter(
            status=JobStatus.QUEUED, created_at__lt=now - timezone.timedelta(days=1)
        )
        for job in forgotten:
            job_fail(job=job, error="no worker picked this job up within a day")
            marked += 1
    return marked


def jobs_fail_for_worker(*, worker: str) -> int:
    """Fail the jobs a restarted worker was running: nobody else will finish them."""
    marked = 0
    for job_model in (TrainingJob, EvaluationJob):
        for job in job_model.objects.filter(
            worker=worker,
            status__in=(JobStatus.INITIALIZING, JobStatus.IN_PROGRESS, JobStatus.STOPPING),
        ):
            job_fail(job=job, error="the worker running this job was restarted; the last "
                                    "checkpoint was kept")  # fmt: skip
            marked += 1
    return marked
