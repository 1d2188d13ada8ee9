"""Queueing a job's Celery task by name, after the job's row is committed.

Services queue tasks through here rather than importing ``training.tasks`` (which calls the
services): the name is the contract, and ``console/celery.py`` routes it to its queue.
:func:`queued_task_ids` tells the orphan reaper which tasks the broker still holds, so a job
whose task vanished (a Redis restart without persistence) is sent again.
"""

from __future__ import annotations

import json
import logging
import time

from celery import current_app

log = logging.getLogger(__name__)

TRAIN_MODEL = "training.tasks.train_model"
EVALUATE_MODEL = "training.tasks.evaluate_model"
EVALUATE_RACE = "training.tasks.evaluate_race"
REPLAY_REWARD = "training.tasks.replay_reward"
VALIDATE_REWARD = "training.tasks.validate_reward"
IMPORT_MODEL = "training.tasks.import_model"
EXPORT_CAR_MODEL = "training.tasks.export_car_model"
CHECK_READINESS = "training.tasks.check_readiness"
JOB_QUEUES = ("training", "evaluation", "readiness")
"""Queues whose tasks carry jobs (see console/celery.py's routes)."""


def send(task_name: str, *args: object, **kwargs: object) -> str:
    """Queue ``task_name`` with these arguments; returns the Celery task id."""
    return current_app.send_task(task_name, args=args, kwargs=kwargs).id


def _task_id(raw: bytes | str) -> str | None:
    try:
        message = json.loads(raw)
    except (TypeError, ValueError):
        return None
    if isinstance(message, list) and message:  # the unacked hash: [message, exchange, key]
        message = message[0]
    if not isinstance(message, dict):
        return None
    headers = message.get("headers") or {}
    props = message.get("properties") or {}
    return headers.get("id") or props.get("correlation_id")


def queued_task_ids(
    queues: tuple[str, ...] = JOB_QUEUES, *, unacked_max_age_s: float | None = None
) -> set[str] | None:
    """Ids of the tasks the broker holds for ``queues``: waiting in a queue, or delivered to a
    worker and not yet acknowledged (tasks are acknowledged late) - only those delivered less
    than ``unacked_max_age_s`` ago when given (a worker claims its job within seconds of the
    delivery; an older unacknowledged delivery of a job still queued belongs to a worker that
    died). None when this cannot be known (the broker is down, or is not Redis): then
    nothing should be sent again."""
    try:
        with current_app.connection_for_write() as conn:
            channel = conn.default_channel
            client = getattr(channel, "client", None)
            if client is None or not hasattr(channel, "_q_for_pri"):
                return None
            # kombu prefixes the keys of the commands it uses itself; LRANGE and HVALS are
            # not among them, so the prefix is added here.
            prefix = getattr(client, "global_keyprefix", "") or ""
            ids: set[str] = set()
            for queue in queues:
                for priority in channel.priority_steps:
                    name = prefix + channel._q_for_pri(queue, priority)
                    for raw in client.execute_command("LRANGE", name, 0, -1):
                        ids.add(_task_id(raw) or "")
            unacked = client.execute_command("HGETALL", prefix + channel.unacked_key)
            if isinstance(unacked, dict):
                unacked = [x for pair in unacked.items() for x in pair]
            delivered = {}
            if unacked_max_age_s is not None:
                scores = client.execute_command(
                    "ZRANGE", prefix + channel.unacked_index_key, 0, -1, "WITHSCORES"
                )
                if isinstance(scores, dict):
                    scores = [x for pair in scores.items() for x in pair]
                delivered = {scores[i]: float(scores[i + 1]) for i in range(0, len(scores), 2)}
            now = time.time()
            for tag, raw in zip(unacked[0::2], unacked[1::2], strict=True):
                if unacked_max_age_s is not None and now - delivered.get(tag, now) > (
                    unacked_max_age_s
                ):
                    continue
                ids.add(_task_id(raw) or "")
    except Exception:  # noqa: BLE001 - any broker failure: presence unknown
        log.warning("could not read the broker's queues", exc_info=True)
        return None
    ids.discard("")
    return ids
