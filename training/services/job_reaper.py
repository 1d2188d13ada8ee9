"""Housekeeping of the job state machine (:mod:`training.services.jobs`): jobs whose worker
died go back to the queue (or fail after too many tries), queued jobs whose task the broker
lost are sent again, and jobs no worker took within a day fail. Every change is a
compare-and-set, so two reapers (or a reaper and a worker) never both act on a job."""

from __future__ import annotations

import logging

from django.db import transaction
from django.db.models import Q
from django.utils import timezone

from training import dispatch
from training.models import RUNNING_JOB_STATUSES, JobStatus, RacingModel, TrainingJob
from training.services.job_runs import job_complete, job_fail
from training.services.job_states import (
    JOB_MODELS,
    Job,
    enqueue_after_commit,
    gave_up_error,
    job_rows,
    max_attempts,
    task_name,
    transition_where,
)

log = logging.getLogger(__name__)


def _requeue(job: Job, *, reason: str) -> bool:
    """A running job whose worker died goes back to QUEUED (compare-and-set on the worker
    that held it) and its task is sent again; after ``max_attempts`` claims it fails, and a
    job its owner was stopping completes. Returns whether this call changed the job."""
    if job.status == JobStatus.STOPPING:
        return job_complete(job=job, stopped_by="user")
    if job.attempts >= max_attempts():
        return job_fail(job=job, error=gave_up_error(job))
    with transaction.atomic():
        requeued = transition_where(
            job, Q(status=job.status, worker=job.worker), to=JobStatus.QUEUED,
            worker="", heartbeat_at=timezone.now(), task_id="",
        )  # fmt: skip
        if requeued:
            if isinstance(job, TrainingJob):
                RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.QUEUED)
            log.warning("job %s queued again: %s", job.pk, reason)
            enqueue_after_commit(job, task_name(job))
    return requeued


def _redispatch_lost(job_model: type[Job], *, grace_s: float) -> int:
    """Send again the task of each queued job that the broker no longer holds (a Redis
    restart without persistence, a flushed queue), once it has waited ``grace_s`` seconds
    since it was queued or last sent. Unknown presence (broker down) sends nothing."""
    before = timezone.now() - timezone.timedelta(seconds=grace_s)
    waiting = list(
        job_rows(job_model)
        .filter(status=JobStatus.QUEUED, created_at__lt=before)
        .filter(Q(heartbeat_at__isnull=True) | Q(heartbeat_at__lt=before))
    )
    if not waiting:
        return 0
    present = dispatch.queued_task_ids(unacked_max_age_s=grace_s)
    if present is None:
        return 0
    sent = 0
    for job in waiting:
        if job.task_id and job.task_id in present:
            continue
        # Mark the send first (compare-and-set on the old task id): two reapers send once.
        marked = job_model.objects.filter(
            pk=job.pk, status=JobStatus.QUEUED, task_id=job.task_id
        ).update(heartbeat_at=timezone.now())
        if not marked:
            continue
        try:
            task_id = dispatch.send(task_name(job), job.pk)
        except Exception:  # noqa: BLE001 - the broker is down: try again next round
            log.warning("could not send job %s again", job.pk, exc_info=True)
            continue
        job_model.objects.filter(pk=job.pk, status=JobStatus.QUEUED).update(task_id=task_id or "")
        log.warning("job %s: its task was lost by the broker; sent again", job.pk)
        sent += 1
    return sent


def jobs_reap_orphans(*, stale_after_s: float = 300.0, lost_task_grace_s: float = 60.0) -> int:
    """Queue again (or, after ``RACECRAFT_JOB_MAX_ATTEMPTS`` claims, fail) running jobs whose
    worker stopped sending heartbeats (killed, lost, crashed); send again the task of queued
    jobs the broker lost; fail queued jobs no worker took within a day. Returns how many jobs
    were acted on."""
    now = timezone.now()
    stale = now - timezone.timedelta(seconds=stale_after_s)
    forgotten_before = now - timezone.timedelta(days=1)
    marked = 0
    for job_model in JOB_MODELS:
        for job in job_rows(job_model).filter(
            status__in=RUNNING_JOB_STATUSES, heartbeat_at__lt=stale
        ):
            marked += _requeue(job, reason="its worker stopped sending heartbeats")
        # Queued (or queued again, or sent again: heartbeat_at marks that) over a day ago.
        marked += _fail_each(
            job_model.objects.filter(status=JobStatus.QUEUED).filter(
                Q(heartbeat_at__lt=forgotten_before)
                | Q(heartbeat_at__isnull=True, created_at__lt=forgotten_before)
            ),
            "no worker picked this job up within a day",
        )
        marked += _redispatch_lost(job_model, grace_s=lost_task_grace_s)
    return marked


def _fail_each(jobs, error: str) -> int:
    return sum(job_fail(job=job, error=error) for job in jobs)


def jobs_requeue_for_worker(*, worker: str) -> int:
    """Queue again the jobs a restarted worker (Celery node ``worker``) was running: its
    processes are gone, so nobody else will finish them; training resumes from its last
    checkpoint."""
    marked = 0
    node = worker[:200]
    for job_model in JOB_MODELS:
        for job in job_rows(job_model).filter(
            Q(worker=worker) | Q(worker__startswith=f"{node}#"),
            status__in=RUNNING_JOB_STATUSES,
        ):
            marked += _requeue(job, reason=f"its worker {worker} was restarted")
    return marked


jobs_fail_for_worker = jobs_requeue_for_worker
"""The former name (a restarted worker's jobs used to fail)."""
