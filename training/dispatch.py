"""Queueing a job's Celery task by name, after the job's row is committed.

Services queue tasks through here rather than importing ``training.tasks`` (which calls the
services): the name is the contract, and ``console/celery.py`` routes it to its queue.
"""

from __future__ import annotations

from celery import current_app

TRAIN_MODEL = "training.tasks.train_model"
EVALUATE_MODEL = "training.tasks.evaluate_model"
SIMULATE_ROLLOUT = "training.tasks.simulate_rollout"
REPLAY_REWARD = "training.tasks.replay_reward"
VALIDATE_REWARD = "training.tasks.validate_reward"


def send(task_name: str, *args: object, **kwargs: object) -> str:
    """Queue ``task_name`` with these arguments; returns the Celery task id."""
    return current_app.send_task(task_name, args=args, kwargs=kwargs).id
