"""Celery tasks: thin interfaces that take ids and call the worker and the services.

Queues by name (console/celery.py): ``train_*`` → training, ``evaluate_*`` → evaluation,
``simulate_*`` → simulation. Services queue these by name (:mod:`training.dispatch`). Jobs
are claimed with a compare-and-set (a retried or duplicated task finds the job taken and
skips), and a worker that starts fails the jobs its previous life left running.
"""

from __future__ import annotations

import socket

from celery import shared_task
from celery.signals import worker_ready
from django.db import close_old_connections

from training import dispatch, services
from training.rollout.remote import serve_rollout
from training.services.analysis import replay_run
from training.services.rewards import reward_validation_run
from training.worker.evaluation import run_evaluation_job
from training.worker.training import run_training_job


@shared_task(bind=True, name=dispatch.TRAIN_MODEL, acks_late=False)
def train_model(self, job_id: int) -> str:
    return run_training_job(job_id, worker=self.request.hostname or "")


@shared_task(bind=True, name=dispatch.EVALUATE_MODEL, acks_late=False)
def evaluate_model(self, evaluation_id: int) -> str:
    return run_evaluation_job(evaluation_id, worker=self.request.hostname or "")


@shared_task(name=dispatch.SIMULATE_ROLLOUT, acks_late=False)
def simulate_rollout(**kwargs) -> str:
    """A rollout worker for a trainer on another machine (queue ``simulation``)."""
    return serve_rollout(**kwargs)


@shared_task(name=dispatch.REPLAY_REWARD)
def replay_reward(model_id: int, iteration: int, episode: int, source: str) -> dict:
    """A reward replay on a recorded episode (the user's code runs in the sandbox here)."""
    return replay_run(model_id, iteration, episode, source)


@shared_task(name=dispatch.VALIDATE_REWARD, acks_late=False, time_limit=600)
def validate_reward(*, source: str, track_id: str, direction: str) -> dict:
    """Validate a user's reward function here, in a worker, never in the web process
    (queue ``default``); the sandbox's own deadlines end it well before ``time_limit``."""
    return reward_validation_run(source=source, track_id=track_id, direction=direction)


@shared_task(name="training.tasks.reap_orphans")
def reap_orphans() -> int:
    return services.jobs_reap_orphans()


@worker_ready.connect
def _fail_jobs_of_my_previous_life(sender=None, **kwargs) -> None:
    """Jobs this host was running when its worker died can never finish: fail them now."""
    close_old_connections()
    name = getattr(sender, "hostname", None) or socket.gethostname()
    services.jobs_fail_for_worker(worker=str(name)[:255])
