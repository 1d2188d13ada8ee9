"""The Celery app "racecraft".

Queues (see docs/architecture.md): ``training`` (trainers), ``simulation`` (rollout workers),
``evaluation`` and ``default``. A task lands on a queue by its name:

    <app>.tasks.train_*      -> training
    <app>.tasks.simulate_*   -> simulation   (also rollout_*)
    <app>.tasks.evaluate_*   -> evaluation
    anything else            -> default

so one machine runs ``-Q training,simulation,evaluation,default`` and a simulation machine
runs ``celery -A console worker -Q simulation``. A task may still pass ``queue=`` explicitly.
"""

from __future__ import annotations

import os

from celery import Celery

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "console.settings")

QUEUE_TRAINING = "training"
QUEUE_SIMULATION = "simulation"
QUEUE_EVALUATION = "evaluation"
QUEUE_DEFAULT = "default"
QUEUES = (QUEUE_TRAINING, QUEUE_SIMULATION, QUEUE_EVALUATION, QUEUE_DEFAULT)

TASK_ROUTES = {
    "*.tasks.train_*": {"queue": QUEUE_TRAINING},
    "*.tasks.simulate_*": {"queue": QUEUE_SIMULATION},
    "*.tasks.rollout_*": {"queue": QUEUE_SIMULATION},
    "*.tasks.evaluate_*": {"queue": QUEUE_EVALUATION},
}

app = Celery("racecraft")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.conf.task_routes = TASK_ROUTES
app.autodiscover_tasks()
