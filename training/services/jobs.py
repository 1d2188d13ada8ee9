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
"""

from __future__ import annotations

import logging
import os
import socket

from django.contrib.auth import get_user_model
from django.db import InterfaceError, OperationalError, connection, transaction
from django.db.models import F, Q
from django.utils import timezone

from training import dispatch, live
from training.errors import ServiceError
from training.models import (
    ACTIVE_JOB_STATUSES,
    RUNNING_JOB_STATUSES,
    EvaluationJob,
    JobStatus,
    RacingModel,
    TrainingJob,
)
from training.rl.evaluation import EvaluationError, EvaluationSettings
from training.services.checks import check_track, limit
from training.services.racing import race_settings
from training.signals import evaluation_finished

log = logging.getLogger(__name__)
Job = TrainingJob | EvaluationJob


# ------------------------------------------------------------------------------ helpers
def _reconnecting(func):
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


def _lock_owner(user) -> None:
    """Serialise one user's job starts (two clicks at once, two tabs): the quota is counted
    under a lock on the owner's row, so it holds under concurrency. Always taken before the
    model's row (one lock order, no deadlock)."""
    get_user_model().objects.select_for_update().filter(pk=user.pk).first()


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
    return _transition_where(job, Q(status__in=allowed), to=to, **fields)


def _transition_where(job: Job, where: Q, *, to: str, **fields) -> bool:
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


def _enqueue_after_commit(job: Job, task_name: str) -> None:
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
        type(job).objects.filter(pk=job.pk).update(task_id=task_id or "")

    transaction.on_commit(go)


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
    race_type: str | None = None,
    race_config: dict | None = None,
    laps: int = 3,
    off_track_penalty_s: float = 2.0,
    crash_penalty_s: float = 5.0,
    purpose: str = "user",
    enqueue: bool = True,
) -> EvaluationJob:
    """Queue an evaluation of a trained model (3-5 laps, DeepRacer's penalties) in a race of
    ``race_type`` with ``race_config``'s boxes or bots (see :mod:`training.services.racing`;
    ``race_type`` None: the model's own race and settings); ``enqueue=False`` leaves it for
    the caller to run in its own process."""
    owned(model, user)
    track_id = track_id or model.track_id
    direction = direction or model.direction
    check_track(track_id, direction)
    if race_type is None:
        race_type, race_config = model.race_type, model.race_config
    race = race_settings(race_type, race_config)
    try:
        EvaluationSettings(laps=laps, off_track_penalty_s=off_track_penalty_s,
                           crash_penalty_s=crash_penalty_s)  # fmt: skip
    except EvaluationError as exc:
        raise ServiceError(str(exc), field="laps" if "laps" in str(exc) else None) from None
    with transaction.atomic():
        if purpose == "user":
            _lock_owner(user)
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if not model.has_checkpoint:
            raise ServiceError("train this model before evaluating it")
        if model_has_active_jobs(model):
            raise ServiceError("this model is busy; wait for its current job to finish")
        if purpose == "user":
            _check_job_quota(user)
        job = EvaluationJob.objects.create(
            model=model, track_id=track_id, direction=direction, race_type=race_type,
            race_config=race, laps=laps, off_track_penalty_s=off_track_penalty_s,
            crash_penalty_s=crash_penalty_s, purpose=purpose,
        )  # fmt: skip
        model.status = RacingModel.Status.EVALUATING
        model.save(update_fields=["status", "updated_at"])
        if enqueue:
            _enqueue_after_commit(job, dispatch.EVALUATE_MODEL)
    return job


# ------------------------------------------------------------------------------ the worker's side
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


def job_claim(*, job_model: type[Job], job_id: int, worker: str) -> Job | None:
    """QUEUED → INITIALIZING for the worker that runs it; None when the job was canceled or
    another worker (a duplicated or retried task) took it first.

    A task given back because its worker process died (``task_reject_on_worker_lost``) finds
    its job still running under that dead process: the claim then takes it over at once
    (compare-and-set on the dead worker's name), and a training job resumes from its last
    checkpoint. ``worker`` is the Celery node name; the job records ``<node>#<pid>``."""
    now = timezone.now()
    job = job_model.objects.select_related("model").get(pk=job_id)
    me = worker_id(worker)
    # The page's clock counts training time already spent before a restart.
    started = now - timezone.timedelta(seconds=_trained_seconds(job))
    fields = dict(started_at=started, heartbeat_at=now, worker=me, attempts=F("attempts") + 1)
    taken = _transition(job, allowed=(JobStatus.QUEUED,), to=JobStatus.INITIALIZING, **fields)
    if not taken and job.status in RUNNING_JOB_STATUSES and runner_is_dead(job.worker, worker):
        if job.status == JobStatus.STOPPING:
            job_complete(job=job, stopped_by="user")  # its owner wanted it to stop anyway
            return None
        if job.attempts >= max_attempts():
            job_fail(job=job, error=_gave_up(job))
            return None
        taken = _transition_where(
            job, Q(status=job.status, worker=job.worker), to=JobStatus.INITIALIZING, **fields
        )
        if taken:
            log.warning("job %s: took over from dead worker process; resuming", job.pk)
    if not taken:
        return None
    if isinstance(job, TrainingJob):
        RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.TRAINING)
    return job


def job_resumed_from(*, job: TrainingJob, description: str) -> None:
    """Record what a training job's network started from (shown with the job)."""
    TrainingJob.objects.filter(pk=job.pk).update(resumed_from=description[:500])
    job.resumed_from = description[:500]


def max_attempts() -> int:
    return limit("RACECRAFT_JOB_MAX_ATTEMPTS", 3)


def _gave_up(job: Job) -> str:
    return (
        f"the worker running this job stopped unexpectedly {job.attempts} times; the last "
        "checkpoint was kept"
    )


def job_begin(*, job: Job) -> bool:
    """INITIALIZING → IN_PROGRESS, unless a stop request came first (it stays STOPPING)."""
    return _transition(job, allowed=(JobStatus.INITIALIZING,), to=JobStatus.IN_PROGRESS)


@_reconnecting
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


@_reconnecting
def job_complete(*, job: Job, on_model_error: str = "", **fields) -> bool:
    """A running job finished: COMPLETED with ``fields`` (results, stopped_by, ...), and its
    model settles. False when the job had already ended (failed by the reaper, say)."""
    with transaction.atomic():
        done = _transition_where(
            job, Q(status__in=RUNNING_JOB_STATUSES, worker=job.worker), to=JobStatus.COMPLETED,
            finished_at=timezone.now(), **fields,
        )  # fmt: skip
        if done:
            model_settle(job.model, on_model_error)
    if done and isinstance(job, EvaluationJob):
        evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
    return done


@_reconnecting
def job_fail(*, job: Job, error: str) -> bool:
    """An active job failed with ``error`` (shown to its owner). False when it had already
    reached a final state, or was queued again and taken by another worker."""
    with transaction.atomic():
        # Only while the job is still the caller's (its worker): a worker cut off while its job
        # was queued again and taken by another cannot end the new run.
        failed = _transition_where(
            job, Q(status__in=ACTIVE_JOB_STATUSES, worker=job.worker), to=JobStatus.FAILED,
            error=error[:2000], finished_at=timezone.now(),
        )  # fmt: skip
        if failed:
            model_settle(job.model, error)
    if failed and isinstance(job, EvaluationJob):
        evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
    return failed


@_reconnecting
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
def task_name(job: Job) -> str:
    return dispatch.TRAIN_MODEL if isinstance(job, TrainingJob) else dispatch.EVALUATE_MODEL


def _requeue(job: Job, *, reason: str) -> bool:
    """A running job whose worker died goes back to QUEUED (compare-and-set on the worker
    that held it) and its task is sent again; after ``max_attempts`` claims it fails, and a
    job its owner was stopping completes. Returns whether this call changed the job."""
    if job.status == JobStatus.STOPPING:
        return job_complete(job=job, stopped_by="user")
    if job.attempts >= max_attempts():
        return job_fail(job=job, error=_gave_up(job))
    with transaction.atomic():
        requeued = _transition_where(
            job, Q(status=job.status, worker=job.worker), to=JobStatus.QUEUED,
            worker="", heartbeat_at=timezone.now(), task_id="",
        )  # fmt: skip
        if requeued:
            if isinstance(job, TrainingJob):
                RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.QUEUED)
            log.warning("job %s queued again: %s", job.pk, reason)
            _enqueue_after_commit(job, task_name(job))
    return requeued


def _redispatch_lost(job_model: type[Job], *, grace_s: float) -> int:
    """Send again the task of each queued job that the broker no longer holds (a Redis
    restart without persistence, a flushed queue), once it has waited ``grace_s`` seconds
    since it was queued or last sent. Unknown presence (broker down) sends nothing."""
    before = timezone.now() - timezone.timedelta(seconds=grace_s)
    waiting = list(
        job_model.objects.filter(status=JobStatus.QUEUED, created_at__lt=before)
        .filter(Q(heartbeat_at__isnull=True) | Q(heartbeat_at__lt=before))
        .select_related("model")
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
    for job_model in (TrainingJob, EvaluationJob):
        for job in job_model.objects.filter(
            status__in=RUNNING_JOB_STATUSES, heartbeat_at__lt=stale
        ).select_related("model"):
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
    for job_model in (TrainingJob, EvaluationJob):
        for job in job_model.objects.filter(
            Q(worker=worker) | Q(worker__startswith=f"{node}#"),
            status__in=RUNNING_JOB_STATUSES,
        ).select_related("model"):
            marked += _requeue(job, reason=f"its worker {worker} was restarted")
    return marked


jobs_fail_for_worker = jobs_requeue_for_worker
"""The former name (a restarted worker's jobs used to fail)."""
