"""Fair dispatch: which queued job a free worker slot runs next.

Every queued job has one Celery task (its *token*) in the broker, so a free slot never idles
while a job waits. Tokens are interchangeable: the slot that receives one runs the *fairest*
queued job of the token's kind, not necessarily the job the token was sent for, and the two
jobs swap task ids, so each queued job still has a token in the broker (the reaper's view,
:func:`~training.services.job_reaper.jobs_reap_orphans`, stays true).

Queued jobs run in rounds, one job of each waiting owner a round:

1. a job's **round** is the owner's turns so far (how many of their jobs of this kind started
   since their oldest waiting job was queued) plus its place among their waiting jobs, so
   someone who queued five jobs at once gets a second only after everyone waiting beside them
   got a first;
2. within a round, the owner with fewer jobs of this kind running now goes first;
3. then the owner whose oldest waiting job is older (first come, first served).

DeepRacer-on-AWS's issue #87 is the failure this prevents: one user's queue of jobs in
front of everyone else's while capacity sits idle.

A league submission's evaluation is an evaluation of its submitter's model, so it takes its
turn here beside their own. Races are dealt the same way among the users they are charged to
(:attr:`RaceJob.owner`: a racer's races from the Races page, a community event's organiser's),
except a race day's (``paced``): a facilitator put it on track now, so its own token runs it
and no other token takes it. Quotas (``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER``) are checked
when a job is queued (:mod:`training.services.jobs`) and hold whatever order the jobs run in;
they count every job a user causes: training, evaluations (their own and their submissions'),
and the races charged to them (a community race's, to its organiser).
"""

from __future__ import annotations

from collections import Counter

from django.db import transaction

from training.models import (
    ACTIVE_JOB_STATUSES,
    RUNNING_JOB_STATUSES,
    EvaluationJob,
    JobStatus,
    RaceJob,
    ReadinessCheck,
    TrainingJob,
)

FAIR_KINDS = (TrainingJob, EvaluationJob, RaceJob, ReadinessCheck)
"""The kinds of job a token may swap within (a race day's race keeps its own token)."""
MAX_WAITING = 2000
"""How many queued jobs the order looks at (quotas keep the queue far shorter)."""


def _owner_field(job_model) -> str:
    """The user a job of ``job_model`` is charged to: a race's owner, else its model's."""
    return "owner_id" if job_model is RaceJob else "model__owner_id"


def fair_order(job_model: type[TrainingJob] | type[EvaluationJob] | type[RaceJob]) -> list[int]:
    """The queued jobs of ``job_model``, fairest first (see the module's rules); a race day's
    races (``paced``) are not in it."""
    owner_of = _owner_field(job_model)
    queued = job_model.objects.filter(status=JobStatus.QUEUED)
    if job_model is RaceJob:
        queued = queued.filter(paced=False)
    waiting = [
        (pk, owner or 0, created)  # 0: a race charged to nobody (a public event's)
        for pk, owner, created in queued.order_by("created_at", "pk").values_list(
            "pk", owner_of, "created_at"
        )[:MAX_WAITING]
    ]
    if not waiting:
        return []
    oldest: dict[int, object] = {}
    for _, owner, created in waiting:
        oldest.setdefault(owner, created)
    users = [owner for owner in oldest if owner]
    started = job_model.objects.filter(
        **{f"{owner_of}__in": users},
        started_at__isnull=False,
        started_at__gte=min(oldest.values()),
    ).values_list(owner_of, "started_at")
    turns = Counter(owner for owner, at in started if at >= oldest[owner])
    running = Counter(
        job_model.objects.filter(
            **{f"{owner_of}__in": users}, status__in=RUNNING_JOB_STATUSES
        ).values_list(owner_of, flat=True)
    )
    place: Counter[int] = Counter()  # the job's place among its owner's waiting jobs
    keyed = []
    for pk, owner, created in waiting:
        round_ = turns[owner] + place[owner]
        place[owner] += 1
        keyed.append(((round_, running[owner], oldest[owner], owner, created, pk), pk))
    ordered = sorted(keyed)
    return [pk for _, pk in ordered]


def token_holder(job_model, job_id: int, task_id: str) -> int:
    """The job a delivered token stands for now: the active job holding its task id (tokens
    move between queued jobs, see the module; a token given back by a dead worker process
    finds the job it was running), else the job it was sent for."""
    if task_id:
        held = (
            job_model.objects.filter(task_id=task_id, status__in=ACTIVE_JOB_STATUSES)
            .values_list("pk", flat=True)
            .first()
        )
        if held is not None:
            return held
    return job_id


def claim_fairest(job_model, holder, *, task_id: str, take) -> object | None:
    """Claim the fairest queued job of ``job_model`` with the token ``task_id``; ``take(pk)``
    is the compare-and-set QUEUED → INITIALIZING that returns the claimed job or None.

    ``holder`` is the queued job the token stood for: when another job is taken, the two swap
    task ids (``holder`` keeps the taken job's token, still in the broker). A spare token
    (``holder`` None: its job was canceled or runs elsewhere) takes a job and leaves it its
    own token, which becomes a spare in turn. Slots racing for a job each try the next one;
    None when no queued job is left."""
    for pk in fair_order(job_model):
        with transaction.atomic():
            job = take(pk)
            if job is None:
                continue  # another slot took it first
            if holder is not None and pk != holder.pk:
                theirs = job.task_id
                job_model.objects.filter(pk=pk).update(task_id=task_id)
                job.task_id = task_id
                job_model.objects.filter(pk=holder.pk, status=JobStatus.QUEUED).update(
                    task_id=theirs
                )
            return job
    return None


def jobs_ahead(job) -> int | None:
    """How many queued jobs of its kind run before ``job`` in the fair order (None unless it
    is queued): what its owner's page shows while it waits."""
    if job is None or job.status != JobStatus.QUEUED or type(job) not in FAIR_KINDS:
        return None
    order = fair_order(type(job))
    return order.index(job.pk) if job.pk in order else None
