"""Celery tasks: thin interfaces that take ids and call the worker and the services.

Queues by name (console/celery.py): ``train_*`` → training, ``evaluate_*`` → evaluation,
``simulate_*`` → simulation; ``validate_*``, ``replay_*``, ``import_*``, ``export_*`` →
interactive (what a page waits for); the rest → default. Services queue these by name
(:mod:`training.dispatch`).

Tasks are acknowledged late and given back to the broker when their worker process dies
(``acks_late`` + ``reject_on_worker_lost``): the job's claim is a compare-and-set, so a
redelivered or duplicated task skips a job another worker holds and takes over one whose
worker process is dead (the training resumes from its last checkpoint). A worker that starts
queues again the jobs its previous life left running. Time limits: console/celery.py.
"""

from __future__ import annotations

import socket

from celery import current_app, shared_task
from celery.signals import worker_init, worker_process_init, worker_ready
from django.db import close_old_connections

from training import dispatch, services, store
from training.rl.algorithms import warm_up
from training.services.analysis import replay_run
from training.services.background import car_export_run, model_import_run, uploads_prune
from training.services.rewards import reward_validation_run
from training.worker.common import SIMULATE_EPISODES, simulate_here
from training.worker.evaluation import run_evaluation_job
from training.worker.race import run_race_job
from training.worker.readiness import run_readiness_check
from training.worker.training import run_training_job

MODEL_QUEUES = frozenset({*dispatch.JOB_QUEUES, "simulation"})
"""The queues of workers whose processes build models: the job queues and the simulation
workers' (console/celery.py names them)."""

_JOB_TASK = {"bind": True, "acks_late": True, "reject_on_worker_lost": True}


@shared_task(name=dispatch.TRAIN_MODEL, **_JOB_TASK)
def train_model(self, job_id: int) -> str:
    return run_training_job(
        job_id, worker=self.request.hostname or "", task_id=self.request.id or ""
    )


@shared_task(name=dispatch.EVALUATE_MODEL, **_JOB_TASK)
def evaluate_model(self, evaluation_id: int) -> str:
    return run_evaluation_job(
        evaluation_id, worker=self.request.hostname or "", task_id=self.request.id or ""
    )


@shared_task(name=SIMULATE_EPISODES, acks_late=False)
def simulate_episodes(**kwargs) -> str:
    """A simulation worker that owns its episodes, for a streamed trainer (queue
    ``simulation``). Acknowledged early: a dead worker's episodes are the trainer's to give to
    another worker, never a task to replay."""
    return simulate_here(**kwargs)


@shared_task(name=dispatch.REPLAY_REWARD)
def replay_reward(model_id: int, iteration: int, episode: int, source: str) -> dict:
    """A reward replay on a recorded episode (the user's code runs in the sandbox here)."""
    return replay_run(model_id, iteration, episode, source)


@shared_task(name=dispatch.VALIDATE_REWARD, acks_late=False, time_limit=600)
def validate_reward(*, source: str, track_id: str, direction: str, user_id: int | None = None
                    ) -> dict:  # fmt: skip
    """Validate a user's reward function here, in a worker, never in the web process
    (queue ``interactive``); the sandbox's own deadlines end it well before ``time_limit``."""
    return reward_validation_run(
        source=source, track_id=track_id, direction=direction, user_id=user_id
    )


@shared_task(name=dispatch.IMPORT_MODEL, acks_late=False)
def import_model(*, owner_id: int, name: str, description: str, upload_key: str) -> dict:
    """Import an uploaded archive the web stored (queue ``interactive``)."""
    return model_import_run(
        owner_id=owner_id, name=name, description=description, upload_key=upload_key
    )


@shared_task(name=dispatch.EXPORT_CAR_MODEL, acks_late=False)
def export_car_model(*, model_id: int) -> dict:
    """Build a model's car archive into the store (queue ``interactive``)."""
    return car_export_run(model_id=model_id)


@shared_task(name="training.tasks.prune_uploads")
def prune_uploads() -> int:
    """Remove uploads whose import never ran (beat, hourly; queue ``default``)."""
    return uploads_prune()


@shared_task(name="training.tasks.reap_orphans", acks_late=True)
def reap_orphans() -> int:
    return services.jobs_reap_orphans()


@worker_init.connect
@worker_process_init.connect
def _patient_store(**kwargs) -> None:
    """Workers retry the object store for long (a checkpoint outlives a store outage); the
    web server gives up quickly and says so."""
    store.use_worker_retries()


@worker_process_init.connect
def _warm_up_job_process(**kwargs) -> None:
    """A process of a worker that runs jobs (training, evaluation, simulation) loads what its
    first job's model would wait for (:func:`training.rl.algorithms.warm_up`); the others
    (the reaper, users' validations) never build one."""
    consumed = set(current_app.amqp.queues.consume_from or ())
    if consumed & MODEL_QUEUES:
        warm_up()


@worker_ready.connect
def _requeue_jobs_of_my_previous_life(sender=None, **kwargs) -> None:
    """Jobs this node was running when its worker died can never finish there: queue them
    again (training resumes from its last checkpoint)."""
    close_old_connections()
    name = getattr(sender, "hostname", None) or socket.gethostname()
    services.jobs_requeue_for_worker(worker=str(name)[:255])


@shared_task(name=dispatch.EVALUATE_RACE, **_JOB_TASK)
def evaluate_race(self, race_id: int, paced: bool = False) -> str:
    """A head-to-head race on an evaluation worker (``paced``: at real time, for a race day).
    The task is a token of the fair order, as a training's is (the slot may run another
    user's queued race; a race day's race runs on its own token)."""
    return run_race_job(race_id, worker=self.request.hostname or "", paced=paced,
                        task_id=self.request.id or "")  # fmt: skip


@shared_task(name=dispatch.CHECK_READINESS, **_JOB_TASK)
def check_readiness(self, check_id: int) -> str:
    """A readiness check (queue ``readiness``), a token of the fair order as an evaluation's."""
    return run_readiness_check(
        check_id, worker=self.request.hostname or "", task_id=self.request.id or ""
    )
