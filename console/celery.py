"""The Celery app "racecraft".

Queues (see docs/architecture.md): ``training`` (trainers), ``simulation`` (rollout workers),
``evaluation`` and ``default``. A task lands on a queue by its name:

    <app>.tasks.train_*      -> training
    <app>.tasks.simulate_*   -> simulation   (also rollout_*)
    <app>.tasks.evaluate_*   -> evaluation
    <app>.tasks.check_readiness -> readiness   (the evaluation worker consumes it too)
    <app>.tasks.validate_*, replay_*, import_*, export_*   -> interactive
    anything else            -> default    (the reaper, the league's periodic tasks)

and ``manage.py up`` runs one worker process per queue (console/launcher.py), so a user's
long jobs never hold the worker that runs the reaper, and a burst of users' validations,
imports or car exports (``interactive``: work a page is waiting for) never delays the reaper
that rescues stuck jobs; a simulation machine runs ``celery -A console worker -Q simulation``.
A task may still pass ``queue=``.

Every task has a soft and a hard time limit (:data:`TIME_LIMITS`; the soft one raises inside
the task, which then fails its job with a message; the hard one kills the process): a job's
task may run as long as the longest job allowed, a quick task a few minutes.
"""

from __future__ import annotations

import os

from celery import Celery

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "console.settings")
# Every process of the console imports this module (console/__init__.py) before torch loads
# OpenMP: its idle threads must sleep, not spin. A trainer's threads spin while simulation
# workers, evaluations, the video and other jobs want the same cores, and steal them: with
# streamed simulation on 2 cores a policy update took 52-54 s spinning and 7-13 s passive
# (bench/bench_video.py --modes streams), while a lockstep training run took the same time
# either way on a quiet machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

QUEUE_TRAINING = "training"
QUEUE_SIMULATION = "simulation"
QUEUE_EVALUATION = "evaluation"
QUEUE_INTERACTIVE = "interactive"
QUEUE_DEFAULT = "default"
QUEUE_READINESS = "readiness"  # readiness checks (issue 51): their own queue
QUEUES = (QUEUE_TRAINING, QUEUE_SIMULATION, QUEUE_EVALUATION, QUEUE_INTERACTIVE, QUEUE_DEFAULT,
          QUEUE_READINESS)  # fmt: skip

TASK_ROUTES = {
    "*.tasks.train_*": {"queue": QUEUE_TRAINING},
    "*.tasks.simulate_*": {"queue": QUEUE_SIMULATION},
    "*.tasks.rollout_*": {"queue": QUEUE_SIMULATION},
    "*.tasks.evaluate_*": {"queue": QUEUE_EVALUATION},
    "*.tasks.check_readiness": {"queue": QUEUE_READINESS},
    "*.tasks.validate_*": {"queue": QUEUE_INTERACTIVE},
    "*.tasks.replay_*": {"queue": QUEUE_INTERACTIVE},
    "*.tasks.import_*": {"queue": QUEUE_INTERACTIVE},
    "*.tasks.export_*": {"queue": QUEUE_INTERACTIVE},
}


def time_limits(job_s: int, evaluation_s: int, quick_s: int) -> dict[str, dict[str, int]]:
    """Per task name: ``soft_time_limit`` and ``time_limit`` (hard, a minute or 5% later)."""

    def pair(soft: int) -> dict[str, int]:
        return {"soft_time_limit": soft, "time_limit": soft + max(60, soft // 20)}

    return {
        "training.tasks.train_model": pair(job_s),
        "training.tasks.simulate_episodes": pair(job_s),
        "training.tasks.evaluate_model": pair(evaluation_s),
        "training.tasks.evaluate_race": pair(evaluation_s),
        "training.tasks.check_readiness": pair(evaluation_s),
        "training.tasks.reap_orphans": pair(min(quick_s, 120)),
        "*": pair(quick_s),
    }


app = Celery("racecraft")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.conf.task_routes = TASK_ROUTES
app.autodiscover_tasks()


def _annotate_time_limits() -> None:
    from django.conf import settings

    limits = time_limits(
        getattr(settings, "RACECRAFT_JOB_TIME_LIMIT_S", 1440 * 60 + 1800),
        getattr(settings, "RACECRAFT_EVALUATION_TIME_LIMIT_S", 1800),
        getattr(settings, "RACECRAFT_QUICK_TASK_TIME_LIMIT_S", 300),
    )
    default = limits.pop("*")
    app.conf.task_soft_time_limit = default["soft_time_limit"]
    app.conf.task_time_limit = default["time_limit"]
    app.conf.task_annotations = limits


TIME_LIMITS = time_limits
_annotate_time_limits()
