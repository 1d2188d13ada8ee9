"""Jobs: the one place a training or evaluation job changes state.

Every change is a compare-and-set on the status (``UPDATE ... WHERE status IN (...)``), so two
writers (a worker and the orphan reaper, two clicks, a retried task) can never both win: a job
reaches one final state, once. The model's status follows its jobs in the same transaction.

    QUEUED ──claim──▶ INITIALIZING ──begin──▶ IN_PROGRESS ──complete──▶ COMPLETED
       │                   │                      │
       └─stop─▶ CANCELED   └────── stop ──▶ STOPPING ──complete──▶ COMPLETED
    any active state ──fail──▶ FAILED
"""

from __future__ import annotations

import logging
import socket

from django.db import transaction
from django.utils import timezone

from training import dispatch, live
from training.errors import ServiceError
from training.models import (
    ACTIVE_JOB_STATUSES,
    RUNNING_JOB_STATUSES,
    EvaluationJob,
    JobStatus,
    RaceType,
    RacingModel,
    TrainingJob,
)
from training.rl.evaluation import EvaluationError, EvaluationSettings
from training.services.checks import SUPPORTED_RACE_TYPES, check_track, limit
from training.signals import evaluation_finished

log = logging.getLogger(__name__)
Job = TrainingJob | EvaluationJob


# ------------------------------------------------------------------------------ helpers
def owned(model: RacingModel, user) -> None:
    """Refuse (as "not found") a model that ``user`` does not own."""
    if model.owner_id != getattr(user, "pk", None):
        raise ServiceError("not found")


def model_has_active_jobs(model: RacingModel) -> bool:
    """Whether any training or evaluation of ``model`` is queued or running."""
    return (
        model.training_jobs.filter(status__in=ACTIVE_JOB_STATUSES).exists()
        or model.evaluations.filter(status__in=ACTIVE_JOB_STATUSES).exists()
    )


def job_kind(job: Job) -> str:
    """``"training"`` or ``"evaluation"``: the job's live group and URL segment."""
    return "training" if isinstance(job, TrainingJob) else "evaluation"


def _active_job_count(user) -> int:
    return (
        TrainingJob.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + EvaluationJob.objects.filter(
            model__owner=user, status__in=ACTIVE_JOB_STATUSES, purpose="user"
        ).count()
    )


def _check_job_quota(user) -> None:
    most = limit("RACECRAFT_MAX_ACTIVE_JOBS_PER_USER", 2)
    if _active_job_count(user) >= most:
        raise ServiceError(
            f"you already have {most} jobs queued or running, the most allowed; wait for one "
            "to finish or stop it"
        )


def _transition(job: Job, *, allowed: tuple[str, ...], to: str, **fields) -> bool:
    """Compare-and-set: move ``job`` to ``to`` if its status is one of ``allowed``.
    Returns whether this call made the change (and tells the job's live group)."""
    changed = type(job).objects.filter(pk=job.pk, status__in=allowed).update(status=to, **fields)
    if not changed:
        return False
    job.status = to
    for name, value in fields.items():
        setattr(job, name, value)
    live.send(live.job_group(job_kind(job), job.pk), {"type": "job.status", "status": to})
    return True


def model_settle(model: RacingModel, error: str = "") -> None:
    """After a job ends: the model is READY when a checkpoint exists, ERROR otherwise."""
    model.refresh_from_db()
    model.status = RacingModel.Status.READY if model.has_checkpoint else RacingModel.Status.ERROR
    if error and not model.has_checkpoint:
        model.error = error
    model.save(update_fields=["status", "error", "updated_at"])


def _enqueue_after_commit(job: Job, task_name: str) -> None:
    """Queue the job's Celery task once its row is committed; if queueing fails, the job is
    failed at once instead of waiting forever."""

    def go() -> None:
        try:
            task_id = dispatch.send(task_name, job.pk)
        except Exception as exc:  # noqa: BLE001 - any broker failure
            log.exception("could not queue job %s", job.pk)
            job_fail(job=job, error=f"the job could not be queued: {exc}")
            return
        type(job).objects.filter(pk=job.pk).update(task_id=task_id or "")

    transaction.on_commit(go)


# ------------------------------------------------------------------------------ starting
def training_start(*, model: RacingModel, user, enqueue: bool = True) -> TrainingJob:
    """Queue a training job for a model that has not been trained yet. ``enqueue=False``
    leaves the job for the caller to run in its own process (the command line)."""
    owned(model, user)
    with transaction.atomic():
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if model.is_busy or model_has_active_jobs(model):
            raise ServiceError("this model is busy; wait for its current job to finish")
        if model.training_jobs.filter(status=JobStatus.COMPLETED).exists():
            raise ServiceError("this model has been trained; clone it to train it further")
        _check_job_quota(user)
        job = TrainingJob.objects.create(model=model, max_minutes=model.max_minutes)
        model.status = RacingModel.Status.QUEUED
        model.error = ""
        model.save(update_fields=["status", "error", "updated_at"])
        if enqueue:
            _enqueue_after_commit(job, dispatch.TRAIN_MODEL)
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
    owned(model, user)
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
        if model_has_active_jobs(model):
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
            _enqueue_after_commit(job, dispatch.EVALUATE_MODEL)
    return job


# ------------------------------------------------------------------------------ the worker's side
def job_claim(*, job_model: type[Job], job_id: int, worker: str) -> Job | None:
    """QUEUED → INITIALIZING for the worker that runs it; None when the job was canceled or
    another worker (a duplicated or retried task) took it first."""
    now = timezone.now()
    job = job_model.objects.select_related("model").get(pk=job_id)
    taken = _transition(
        job, allowed=(JobStatus.QUEUED,), to=JobStatus.INITIALIZING, started_at=now,
        heartbeat_at=now, worker=(worker or socket.gethostname())[:255],
    )  # fmt: skip
    if not taken:
        return None
    if isinstance(job, TrainingJob):
        RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.TRAINING)
    return job


def job_begin(*, job: Job) -> bool:
    """INITIALIZING → IN_PROGRESS, unless a stop request came first (it stays STOPPING)."""
    return _transition(job, allowed=(JobStatus.INITIALIZING,), to=JobStatus.IN_PROGRESS)


def job_stop_requested(*, job: Job) -> bool:
    """Whether the job's owner asked it to stop (the worker polls this)."""
    return type(job).objects.filter(pk=job.pk, stop_requested=True).exists()


def job_complete(*, job: Job, on_model_error: str = "", **fields) -> bool:
    """A running job finished: COMPLETED with ``fields`` (results, stopped_by, ...), and its
    model settles. False when the job had already ended (failed by the reaper, say)."""
    with transaction.atomic():
        done = _transition(
            job, allowed=RUNNING_JOB_STATUSES, to=JobStatus.COMPLETED,
            finished_at=timezone.now(), **fields,
        )  # fmt: skip
        if done:
            model_settle(job.model, on_model_error)
    if done and isinstance(job, EvaluationJob):
        evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
    return done


def job_fail(*, job: Job, error: str) -> bool:
    """An active job failed with ``error`` (shown to its owner). False when it had already
    reached a final state."""
    with transaction.atomic():
        failed = _transition(
            job, allowed=ACTIVE_JOB_STATUSES, to=JobStatus.FAILED, error=error[:2000],
            finished_at=timezone.now(),
        )  # fmt: skip
        if failed:
            model_settle(job.model, error)
    if failed and isinstance(job, EvaluationJob):
        evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
    return failed


def job_heartbeat(*, job_model: type[Job], job_id: int, **progress) -> None:
    """The worker is alive (and, optionally, how far it got: ``laps_done``, ``iterations``)."""
    job_model.objects.filter(pk=job_id).update(heartbeat_at=timezone.now(), **progress)


# ------------------------------------------------------------------------------ the owner's side
def job_stop(*, job: Job, user) -> Job:
    """Stop a job: a queued one is canceled at once; a running one stops at the next safe
    point and keeps its last checkpoint (cooperative: the worker polls the flag)."""
    owned(job.model, user)
    with transaction.atomic():
        if _transition(
            job, allowed=(JobStatus.QUEUED,), to=JobStatus.CANCELED,
            finished_at=timezone.now(), stop_requested=True,
        ):  # fmt: skip
            model_settle(job.model)
            if isinstance(job, EvaluationJob):
                evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
        elif _transition(
            job, allowed=(JobStatus.INITIALIZING, JobStatus.IN_PROGRESS),
            to=JobStatus.STOPPING, stop_requested=True,
        ):  # fmt: skip
            RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.STOPPING)
        elif not type(job).objects.filter(pk=job.pk, status=JobStatus.STOPPING).exists():
            raise ServiceError("this job has already finished")
    return job


# ------------------------------------------------------------------------------ housekeeping
def _fail_each(jobs, error: str) -> int:
    return sum(job_fail(job=job, error=error) for job in jobs)


def jobs_reap_orphans(*, stale_after_s: float = 300.0) -> int:
    """Fail active jobs whose worker stopped sending heartbeats (killed, lost, crashed), and
    queued jobs that no worker took within a day. Returns how many were marked."""
    now = timezone.now()
    stale = now - timezone.timedelta(seconds=stale_after_s)
    forgotten_before = now - timezone.timedelta(days=1)
    marked = 0
    for job_model in (TrainingJob, EvaluationJob):
        marked += _fail_each(
            job_model.objects.filter(status__in=RUNNING_JOB_STATUSES, heartbeat_at__lt=stale),
            "the worker running this job stopped unexpectedly; the last checkpoint was kept",
        )
        marked += _fail_each(
            job_model.objects.filter(status=JobStatus.QUEUED, created_at__lt=forgotten_before),
            "no worker picked this job up within a day",
        )
    return marked


def jobs_fail_for_worker(*, worker: str) -> int:
    """Fail the jobs a restarted worker was running: nobody else will finish them."""
    marked = 0
    for job_model in (TrainingJob, EvaluationJob):
        marked += _fail_each(
            job_model.objects.filter(worker=worker, status__in=RUNNING_JOB_STATUSES),
            "the worker running this job was restarted; the last checkpoint was kept",
        )
    return marked
