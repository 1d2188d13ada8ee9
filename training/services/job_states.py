"""The parts of the job state machine (:mod:`training.services.jobs`) that every side of it
shares: the compare-and-set on a job's status, which tells the job's live group only after
the commit; queueing a job's task after the commit; the model settling when a job ends; and
the reconnect-once guard for the calls a running worker makes."""

from __future__ import annotations

import logging

from django.db import InterfaceError, OperationalError, connection, transaction
from django.db.models import Q

from training import dispatch, live
from training.errors import ServiceError
from training.models import (
    ACTIVE_JOB_STATUSES,
    EvaluationJob,
    RaceJob,
    RacingModel,
    ReadinessCheck,
    TrainingJob,
)
from training.services.checks import limit
from training.signals import evaluation_finished, race_finished

log = logging.getLogger(__name__)
Job = TrainingJob | EvaluationJob | RaceJob | ReadinessCheck
JOB_MODELS: tuple[type[Job], ...] = (TrainingJob, EvaluationJob, RaceJob, ReadinessCheck)
"""Every kind of job the reaper looks after."""


def job_rows(job_model: type[Job]):
    """``job_model``'s rows, with their model fetched along for the jobs that have one."""
    rows = job_model.objects.all()
    return rows if job_model is RaceJob else rows.select_related("model")


def job_settle(job: Job, error: str = "") -> None:
    """After a job ends: its model settles (:func:`model_settle`); a race has several
    models and changes none of them."""
    if not isinstance(job, RaceJob):
        model_settle(job.model, error)


def job_ended(job: Job) -> None:
    """Tell whoever listens that an evaluation or a race reached a final state."""
    if isinstance(job, EvaluationJob):
        evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
    elif isinstance(job, RaceJob):
        race_finished.send(sender=RaceJob, race_id=job.pk)


def reconnecting(func):
    """For the calls a running worker makes (heartbeats, stop polls, the final state): if the
    database connection was dropped (a restart, a failover, an idle kill), reconnect once and
    try again, instead of failing a long job or leaving it stuck. Inside a transaction the
    error is raised as it is (the transaction is lost anyway)."""

    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (OperationalError, InterfaceError):
            if connection.in_atomic_block:
                raise
            log.warning("database connection lost in %s; reconnecting", func.__name__)
            connection.close()
            return func(*args, **kwargs)

    wrapper.__name__ = func.__name__
    wrapper.__qualname__ = func.__qualname__
    wrapper.__doc__ = func.__doc__
    wrapper.__wrapped__ = func
    return wrapper


def owned(model: RacingModel, user) -> None:
    """Refuse (as "not found") a model that ``user`` does not own."""
    if model.owner_id != getattr(user, "pk", None):
        raise ServiceError("not found")


def model_has_active_jobs(model: RacingModel) -> bool:
    """Whether any training or evaluation of ``model`` is queued or running."""
    return (
        model.training_jobs.filter(status__in=ACTIVE_JOB_STATUSES).exists()
        or model.evaluations.filter(status__in=ACTIVE_JOB_STATUSES).exists()
        or model.readiness_checks.filter(status__in=ACTIVE_JOB_STATUSES).exists()
    )


def job_kind(job: Job) -> str:
    """``"training"``, ``"evaluation"`` or ``"race"``: the job's live group."""
    if isinstance(job, RaceJob):
        return "race"
    if isinstance(job, ReadinessCheck):
        return "readiness"
    return "training" if isinstance(job, TrainingJob) else "evaluation"


def transition(job: Job, *, allowed: tuple[str, ...], to: str, **fields) -> bool:
    """Compare-and-set: move ``job`` to ``to`` if its status is one of ``allowed``.
    Returns whether this call made the change (and tells the job's live group)."""
    return transition_where(job, Q(status__in=allowed), to=to, **fields)


def transition_where(job: Job, where: Q, *, to: str, **fields) -> bool:
    """Compare-and-set on any condition ``where`` (status, worker, heartbeat...)."""
    changed = type(job).objects.filter(where, pk=job.pk).update(status=to, **fields)
    if not changed:
        return False
    job.status = to
    computed = []
    for name, value in fields.items():
        if hasattr(value, "resolve_expression"):
            computed.append(name)
        else:
            setattr(job, name, value)
    if computed:
        job.refresh_from_db(fields=computed)
    _broadcast_after_commit(job, to)
    return True


def _broadcast_after_commit(job: Job, status: str) -> None:
    """Tell the job's live group its new status once the change is committed (at once outside
    a transaction): a browser never sees a status the database may still roll back."""
    group = live.job_group(job_kind(job), job.pk)
    transaction.on_commit(lambda: live.send(group, {"type": "job.status", "status": status}))


def model_settle(model: RacingModel, error: str = "") -> None:
    """After a job ends: the model is READY when a checkpoint exists, ERROR otherwise."""
    model.refresh_from_db()
    model.status = RacingModel.Status.READY if model.has_checkpoint else RacingModel.Status.ERROR
    if error and not model.has_checkpoint:
        model.error = error
    model.save(update_fields=["status", "error", "updated_at"])


BROKER_DOWN_NOTE = (
    "the task queue cannot be reached right now; the job stays queued and is sent to a worker "
    "as soon as the queue is back (checked every two minutes)"
)
"""What the page says when a job was saved but its task could not be sent."""


def enqueue_after_commit(job: Job, task_name: str) -> None:
    """Queue the job's Celery task once its row is committed. If the broker cannot be reached
    the job stays QUEUED without a task id: the reaper (:func:`jobs_reap_orphans`) sends it
    once the broker answers again, and ``job.dispatch_note`` (not stored) tells the caller."""

    def go() -> None:
        try:
            task_id = dispatch.send(task_name, job.pk)
        except Exception:  # noqa: BLE001 - any broker failure: the reaper sends it later
            log.warning("could not queue job %s; the reaper sends it later", job.pk, exc_info=True)
            job.dispatch_note = BROKER_DOWN_NOTE
            return
        # Unless a worker already gave the job another token (fair dispatch swaps tokens).
        type(job).objects.filter(pk=job.pk, task_id="").update(task_id=task_id or "")

    transaction.on_commit(go)


def max_attempts() -> int:
    return limit("RACECRAFT_JOB_MAX_ATTEMPTS", 3)


def gave_up_error(job: Job) -> str:
    return (
        f"the worker running this job stopped unexpectedly {job.attempts} times; the last "
        "checkpoint was kept"
    )


def task_name(job: Job) -> str:
    if isinstance(job, RaceJob):
        return dispatch.EVALUATE_RACE
    if isinstance(job, ReadinessCheck):
        return dispatch.CHECK_READINESS
    return dispatch.TRAIN_MODEL if isinstance(job, TrainingJob) else dispatch.EVALUATE_MODEL
