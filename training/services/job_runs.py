"""The worker's side of the job state machine (:mod:`training.services.jobs`): claiming a
job (or taking it over from a dead worker process), beginning, heartbeats, the stop poll, and
the one final state (completed or failed)."""

from __future__ import annotations

import logging
import os
import socket

from django.db import transaction
from django.db.models import F, Q
from django.utils import timezone

from training.models import (
    ACTIVE_JOB_STATUSES,
    RUNNING_JOB_STATUSES,
    JobStatus,
    RacingModel,
    TrainingJob,
)
from training.services.job_queue import FAIR_KINDS, claim_fairest, token_holder
from training.services.job_states import (
    Job,
    gave_up_error,
    job_ended,
    job_rows,
    job_settle,
    max_attempts,
    reconnecting,
    transition,
    transition_where,
)

log = logging.getLogger(__name__)


def worker_id(node: str) -> str:
    """How a job names the process that runs it: ``<celery node>#<pid>``."""
    return f"{(node or socket.gethostname())[:200]}#{os.getpid()}"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def runner_is_dead(worker: str, node: str) -> bool:
    """Whether the process named ``worker`` (see :func:`worker_id`) is provably gone: it ran
    on this node (this machine) and its pid no longer exists."""
    name, _, pid = worker.rpartition("#")
    if not name or name != (node or socket.gethostname())[:200] or not pid.isdigit():
        return False
    return int(pid) != os.getpid() and not _pid_alive(int(pid))


def _trained_seconds(job: Job) -> float:
    """Training time a job already used in finished iterations (0 for a fresh job)."""
    if not isinstance(job, TrainingJob):
        return 0.0
    last = job.iterations_set.order_by("-iteration").values_list("elapsed_s", flat=True).first()
    return float(last or 0.0)


def job_claim(*, job_model: type[Job], job_id: int, worker: str, task_id: str = "") -> Job | None:
    """Claim a queued job for the worker slot that received the task ``task_id`` (sent for
    ``job_id``): QUEUED → INITIALIZING. Training and evaluation tasks are interchangeable
    tokens: the slot runs the fairest queued job of the kind (:mod:`~.job_queue`), which may
    be another user's; a caller without a task (the command line) claims ``job_id`` itself.
    None when no job is left to run (canceled, or taken by another slot).

    A task given back because its worker process died (``task_reject_on_worker_lost``) finds
    its job still running under that dead process: the claim then takes it over at once
    (compare-and-set on the dead worker's name), and a training job resumes from its last
    checkpoint. ``worker`` is the Celery node name; the job records ``<node>#<pid>``."""
    fair = job_model in FAIR_KINDS and bool(task_id)  # no task: a caller runs its own job
    if fair:
        job_id = token_holder(job_model, job_id, task_id)
    job = job_rows(job_model).filter(pk=job_id).first()
    if getattr(job, "paced", False):
        fair = False  # a race day's race: on track now, with its own token (job_queue.py)
    me = worker_id(worker)

    def fields_for(job: Job) -> dict:
        now = timezone.now()
        # The page's clock counts training time already spent before a restart.
        started = now - timezone.timedelta(seconds=_trained_seconds(job))
        return dict(started_at=started, heartbeat_at=now, worker=me, attempts=F("attempts") + 1)

    def take(pk: int) -> Job | None:
        queued = job_rows(job_model).filter(pk=pk, status=JobStatus.QUEUED).first()
        if queued is None:
            return None
        allowed = (JobStatus.QUEUED,)
        return queued if transition(queued, allowed=allowed, to=JobStatus.INITIALIZING,
                                    **fields_for(queued)) else None  # fmt: skip

    if (
        job is not None
        and job.status in RUNNING_JOB_STATUSES
        and runner_is_dead(job.worker, worker)
    ):
        if job.status == JobStatus.STOPPING:
            job_complete(job=job, stopped_by="user")  # its owner wanted it to stop anyway
            return None
        if job.attempts >= max_attempts():
            job_fail(job=job, error=gave_up_error(job))
            return None
        where = Q(status=job.status, worker=job.worker)
        if not transition_where(job, where, to=JobStatus.INITIALIZING, **fields_for(job)):
            return None
        log.warning("job %s: took over from dead worker process; resuming", job.pk)
        taken = job
    elif fair:
        holder = job if job is not None and job.status == JobStatus.QUEUED else None
        taken = claim_fairest(job_model, holder, task_id=task_id, take=take)
    else:
        taken = take(job_id) if job is not None else None
    if taken is not None and isinstance(taken, TrainingJob):
        RacingModel.objects.filter(pk=taken.model_id).update(status=RacingModel.Status.TRAINING)
    return taken


def job_resumed_from(*, job: TrainingJob, description: str) -> None:
    """Record what a training job's network started from (shown with the job)."""
    TrainingJob.objects.filter(pk=job.pk).update(resumed_from=description[:500])
    job.resumed_from = description[:500]


def job_begin(*, job: Job) -> bool:
    """INITIALIZING → IN_PROGRESS, unless a stop request came first (it stays STOPPING)."""
    return transition(job, allowed=(JobStatus.INITIALIZING,), to=JobStatus.IN_PROGRESS)


@reconnecting
def job_stop_requested(*, job: Job) -> bool:
    """Whether the worker should stop: its owner asked, or the job is no longer this worker's
    (queued again and taken by another while this one was cut off). The worker polls this."""
    return (
        not type(job)
        .objects.filter(
            pk=job.pk, stop_requested=False, worker=job.worker, status__in=RUNNING_JOB_STATUSES
        )
        .exists()
    )


@reconnecting
def job_complete(*, job: Job, on_model_error: str = "", **fields) -> bool:
    """A running job finished: COMPLETED with ``fields`` (results, stopped_by, ...), and its
    model settles. False when the job had already ended (failed by the reaper, say)."""
    with transaction.atomic():
        done = transition_where(
            job, Q(status__in=RUNNING_JOB_STATUSES, worker=job.worker), to=JobStatus.COMPLETED,
            finished_at=timezone.now(), **fields,
        )  # fmt: skip
        if done:
            job_settle(job, on_model_error)
    if done:
        job_ended(job)
    return done


@reconnecting
def job_fail(*, job: Job, error: str) -> bool:
    """An active job failed with ``error`` (shown to its owner). False when it had already
    reached a final state, or was queued again and taken by another worker."""
    with transaction.atomic():
        # Only while the job is still the caller's (its worker): a worker cut off while its job
        # was queued again and taken by another cannot end the new run.
        failed = transition_where(
            job, Q(status__in=ACTIVE_JOB_STATUSES, worker=job.worker), to=JobStatus.FAILED,
            error=error[:2000], finished_at=timezone.now(),
        )  # fmt: skip
        if failed:
            job_settle(job, error)
    if failed:
        job_ended(job)
    return failed


@reconnecting
def job_heartbeat(*, job_model: type[Job], job_id: int, **progress) -> None:
    """The worker is alive (and, optionally, how far it got: ``laps_done``, ``iterations``)."""
    job_model.objects.filter(pk=job_id).update(heartbeat_at=timezone.now(), **progress)
