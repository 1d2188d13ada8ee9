"""A Celery app for the dispatch load test (tests/faults/test_fair_dispatch.py): the console's
own app, tasks, routes, broker and database, but a training job's body is a stand-in that
holds its worker slot for ``STANDIN_JOB_S`` seconds. Claiming (fair dispatch, the token swap),
completing, Celery, Redis and PostgreSQL are the real ones.

    python -m celery -A tests.faults.standin_jobs worker -Q training -c 1
"""

from __future__ import annotations

import os
import time

from celery.signals import worker_process_init

from console.celery import app

__all__ = ["app"]


def _standin(job_id: int, worker: str = "", task_id: str = "") -> str:
    from training import services
    from training.models import TrainingJob

    job = services.job_claim(job_model=TrainingJob, job_id=job_id, worker=worker, task_id=task_id)
    if job is None:
        return "skipped"
    services.job_begin(job=job)
    time.sleep(float(os.environ.get("STANDIN_JOB_S", "0.5")))
    services.job_complete(job=job, stopped_by="time")
    return "completed"


@worker_process_init.connect
def _stand_in(**kwargs) -> None:
    import training.tasks

    training.tasks.run_training_job = _standin
