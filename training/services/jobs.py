"""Jobs: the one place a training or evaluation job changes state.

Every change is a compare-and-set on the status (``UPDATE ... WHERE status IN (...)``), so two
writers (a worker and the orphan reaper, two clicks, a retried task) can never both win: a job
reaches one final state, once. The model's status follows its jobs in the same transaction.

    QUEUED ──claim──▶ INITIALIZING ──begin──▶ IN_PROGRESS ──complete──▶ COMPLETED
       │                   │                      │
       └─stop─▶ CANCELED   └────── stop ──▶ STOPPING ──complete──▶ COMPLETED
    any active state ──fail──▶ FAILED
    INITIALIZING, IN_PROGRESS ──requeue (its worker died)──▶ QUEUED   (at most
        RACECRAFT_JOB_MAX_ATTEMPTS claims; a training job then resumes from its last checkpoint)

Nothing is lost or stuck when a worker or the broker dies: tasks are acknowledged late and
given back when their worker is lost (console/celery.py); a claim takes over a job whose
worker process is provably dead; the periodic reaper (:func:`jobs_reap_orphans`) queues again
the running jobs whose heartbeats stopped and sends again the task of a queued job that the
broker no longer holds. Every one of these is a compare-and-set, so duplicates are harmless.

This module starts and stops jobs (the owner's side) and is where every job service is
imported from; the rest lives beside it: job_states.py (the compare-and-set, broadcasts and
task dispatch after commit, the model settling), job_runs.py (the worker's side: claim, begin,
heartbeat, complete, fail), job_reaper.py (orphans, lost tasks, a restarted worker's jobs).
"""

from __future__ import annotations

from django.contrib.auth import get_user_model
from django.db import transaction
from django.utils import timezone

from training import dispatch
from training.errors import ServiceError
from training.models import (
    ACTIVE_JOB_STATUSES,
    EvaluationJob,
    JobStatus,
    RaceJob,
    RacingModel,
    ReadinessCheck,
    TrainingJob,
)
from training.rl.evaluation import EvaluationError, EvaluationSettings
from training.services.checks import check_track, limit
from training.services.conditions import conditions_check
from training.services.job_reaper import (
    jobs_fail_for_worker,
    jobs_reap_orphans,
    jobs_requeue_for_worker,
)
from training.services.job_runs import (
    job_begin,
    job_claim,
    job_complete,
    job_fail,
    job_heartbeat,
    job_resumed_from,
    job_stop_requested,
    runner_is_dead,
    worker_id,
)
from training.services.job_states import (
    BROKER_DOWN_NOTE,
    Job,
    enqueue_after_commit,
    job_kind,
    max_attempts,
    model_has_active_jobs,
    model_settle,
    owned,
    task_name,
    transition,
)
from training.services.racing import race_settings
from training.services.trackfiles import tracks_check_recorded
from training.signals import evaluation_finished

__all__ = [
    "BROKER_DOWN_NOTE",
    "Job",
    "JobQuotaError",
    "evaluation_start",
    "job_begin",
    "job_claim",
    "job_complete",
    "job_fail",
    "job_heartbeat",
    "job_kind",
    "job_quota_hold",
    "job_resumed_from",
    "job_stop",
    "job_stop_requested",
    "jobs_fail_for_worker",
    "jobs_reap_orphans",
    "jobs_requeue_for_worker",
    "max_attempts",
    "model_has_active_jobs",
    "model_settle",
    "owned",
    "runner_is_dead",
    "task_name",
    "training_start",
    "worker_id",
]


class JobQuotaError(ServiceError):
    """A job refused because its user already has ``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER`` jobs
    queued or running (callers that queue jobs for a user, the league, word it for theirs)."""

    def __init__(self, message: str, most: int) -> None:
        super().__init__(message)
        self.most = most


def _active_job_count(user) -> int:
    """Every job ``user`` causes that is queued or running: their training jobs, every
    evaluation of their models (their own and their league submissions'), and the races
    charged to them (:attr:`RaceJob.owner`: their own races and their community events')."""
    return (
        TrainingJob.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + EvaluationJob.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + RaceJob.objects.filter(owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + ReadinessCheck.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
    )


def _lock_owner(user) -> None:
    """Serialise one user's job starts (two clicks at once, two tabs): the quota is counted
    under a lock on the owner's row, so it holds under concurrency. Always taken before the
    model's row (one lock order, no deadlock). FOR NO KEY UPDATE: it serialises the quota
    counts yet lets rows that merely refer to the user (a submission, a notification) be
    written beside it."""
    get_user_model().objects.select_for_update(no_key=True).filter(pk=user.pk).first()


def _check_job_quota(user) -> None:
    most = limit("RACECRAFT_MAX_ACTIVE_JOBS_PER_USER", 2)
    if _active_job_count(user) >= most:
        raise JobQuotaError(
            f"you already have {most} jobs queued or running, the most allowed (training, "
            "evaluations, league submissions and your events' races all count); wait for one "
            "to finish or stop it",
            most,
        )


def job_quota_hold(*, user) -> None:
    """Hold ``user`` to their quota before a job charged to them is created: call it inside
    the transaction that creates the job (the user's row stays locked until the commit, so
    two starts at once cannot both pass). Raises :class:`JobQuotaError`."""
    if not transaction.get_connection().in_atomic_block:
        raise RuntimeError("job_quota_hold must run inside the transaction that queues the job")
    _lock_owner(user)
    _check_job_quota(user)


# ------------------------------------------------------------------------------ starting
def training_start(*, model: RacingModel, user, enqueue: bool = True) -> TrainingJob:
    """Queue a training job for a model that has not been trained yet. ``enqueue=False``
    leaves the job for the caller to run in its own process (the command line)."""
    owned(model, user)
    with transaction.atomic():
        _lock_owner(user)
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if model.is_busy or model_has_active_jobs(model):
            raise ServiceError("this model is busy; wait for its current job to finish")
        if model.training_jobs.filter(status=JobStatus.COMPLETED).exists():
            raise ServiceError("this model has been trained; clone it to train it further")
        tracks_check_recorded([track_id for track_id, _ in model.training_tracks])
        _check_job_quota(user)
        job = TrainingJob.objects.create(model=model, max_minutes=model.max_minutes,
                                         stop_when_ready=model.stop_when_ready)  # fmt: skip
        model.status = RacingModel.Status.QUEUED
        model.error = ""
        model.save(update_fields=["status", "error", "updated_at"])
        if enqueue:
            enqueue_after_commit(job, dispatch.TRAIN_MODEL)
    return job


def evaluation_start(
    *,
    model: RacingModel,
    user,
    track_id: str | None = None,
    direction: str | None = None,
    race_type: str | None = None,
    race_config: dict | None = None,
    laps: int = 3,
    off_track_penalty_s: float = 2.0,
    crash_penalty_s: float = 5.0,
    purpose: str = "user",
    enqueue: bool = True,
    conditions: dict | None = None,
    conditions_seed: int | None = None,
) -> EvaluationJob:
    """Queue an evaluation of a trained model (3-5 laps, DeepRacer's penalties) in a race of
    ``race_type`` with ``race_config``'s boxes or bots (see :mod:`training.services.racing`;
    ``race_type`` None: the model's own race and settings); ``enqueue=False`` leaves it for
    the caller to run in its own process. ``conditions`` (a league event's outside-world
    setting, drawn from ``conditions_seed``): the world it drives in; None: the clean world.
    Every ``purpose`` counts against the model owner's
    job quota (a league submission's evaluation is its submitter's job): raises
    :class:`JobQuotaError` when it is full."""
    owned(model, user)
    track_id = track_id or model.track_id
    direction = direction or model.direction
    check_track(track_id, direction)
    tracks_check_recorded([track_id])  # every worker can have it, or it is refused here
    if race_type is None:
        race_type, race_config = model.race_type, model.race_config
    race = race_settings(race_type, race_config)
    world = conditions_check(conditions)
    try:
        EvaluationSettings(laps=laps, off_track_penalty_s=off_track_penalty_s,
                           crash_penalty_s=crash_penalty_s)  # fmt: skip
    except EvaluationError as exc:
        raise ServiceError(str(exc), field="laps" if "laps" in str(exc) else None) from None
    with transaction.atomic():
        _lock_owner(user)  # a league submission's evaluation is its submitter's job too
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if not model.has_checkpoint:
            raise ServiceError("train this model before evaluating it")
        if model_has_active_jobs(model):
            raise ServiceError("this model is busy; wait for its current job to finish")
        _check_job_quota(user)
        job = EvaluationJob.objects.create(
            model=model, track_id=track_id, direction=direction, race_type=race_type,
            race_config=race, laps=laps, off_track_penalty_s=off_track_penalty_s,
            crash_penalty_s=crash_penalty_s, purpose=purpose, conditions=world,
            conditions_seed=conditions_seed if world else None,
        )  # fmt: skip
        model.status = RacingModel.Status.EVALUATING
        model.save(update_fields=["status", "updated_at"])
        if enqueue:
            enqueue_after_commit(job, dispatch.EVALUATE_MODEL)
    return job


# ------------------------------------------------------------------------------ the owner's side
def job_stop(*, job: Job, user) -> Job:
    """Stop a job: a queued one is canceled at once; a running one stops at the next safe
    point and keeps its last checkpoint (cooperative: the worker polls the flag)."""
    owned(job.model, user)
    with transaction.atomic():
        if transition(
            job, allowed=(JobStatus.QUEUED,), to=JobStatus.CANCELED,
            finished_at=timezone.now(), stop_requested=True,
        ):  # fmt: skip
            model_settle(job.model)
            if isinstance(job, EvaluationJob):
                evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
        elif transition(
            job, allowed=(JobStatus.INITIALIZING, JobStatus.IN_PROGRESS),
            to=JobStatus.STOPPING, stop_requested=True,
        ):  # fmt: skip
            RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.STOPPING)
        elif not type(job).objects.filter(pk=job.pk, status=JobStatus.STOPPING).exists():
            raise ServiceError("this job has already finished")
    return job
