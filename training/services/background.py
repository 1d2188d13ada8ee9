"""Model imports and car-model exports as Celery tasks: nothing untrusted or heavy in a web
request (issue 10).

- **Import**: :func:`model_import_start` checks what is cheap to check (the name, the quota),
  stores the upload as it came in the object store under ``racecraft-uploads/`` (any worker
  machine reads it from there; no model folder can be named so), and queues
  ``training.tasks.import_model``. The worker (:func:`model_import_run`) reads the archive with
  :func:`~training.services.model_imports.model_import` (all or nothing) and removes the upload.
- **Car export**: :func:`car_export_ready` hands over an archive already built (the store
  keeps it at the model's ``car_export`` key); otherwise :func:`car_export_start` queues
  ``training.tasks.export_car_model``, whose worker builds it into the store
  (:func:`~training.services.downloads.car_model_archive`, the one builder:
  :func:`~training.services.downloads.car_archive_build`); the page then offers the download.

Both run on the ``interactive`` queue (console/celery.py). The page polls
:func:`background_status` with the task id, which only the user who started it may read. Per
user at most ``RACECRAFT_BACKGROUND_TASKS_PER_USER`` imports and exports are queued or running
at once (counted in Redis, so every web process sees the same count); one export per model
runs at a time (a second request follows the first one's task).

A worker's answer is a small dict: ``{"ok": True, "model_id": ..., "note": ...}`` or
``{"ok": False, "error": <a sentence>, "field": ...}``; errors are the services' messages
(never object keys, store folders or endpoints: see ``store_failure``).
"""

from __future__ import annotations

import logging
import time
import uuid
from typing import Any, TypedDict

import redis
from celery import current_app
from celery.result import AsyncResult
from django.conf import settings
from django.contrib.auth import get_user_model

from training.dispatch import EXPORT_CAR_MODEL, IMPORT_MODEL
from training.errors import ServiceError
from training.models import RacingModel
from training.services.checks import check_model_quota, check_name
from training.services.downloads import car_archive_stored, car_model_archive
from training.services.model_files import store_failure
from training.services.model_imports import model_import
from training.storage import ObjectNotFound, StoreError, StoreUnavailable
from training.store import get_store

log = logging.getLogger(__name__)
#: How long a task id stays readable and a slot taken without an answer (seconds).
KEY_TTL_S = 60 * 60
UPLOADS = "racecraft-uploads/"
#: Uploads older than this were never imported (the task was lost): removed by beat (seconds).
UPLOAD_MAX_AGE_S = 24 * 3600
QUEUE_DOWN = (
    "the task queue cannot be reached right now, so nothing was started; try again in a minute"
)


class BackgroundStatus(TypedDict, total=False):
    """``status``: queued | running | done; when done, ``ok`` and the worker's answer."""

    status: str
    kind: str
    ok: bool
    error: str
    field: str | None
    model_id: int
    note: str


class TaskNotFound(ServiceError):
    """No background task with this id belongs to this user."""


def _client() -> redis.Redis:
    return redis.Redis.from_url(settings.REDIS_URL)


def _key(*parts: object) -> str:
    return f"{settings.REDIS_PREFIX}racecraft:background:" + ":".join(map(str, parts))


def _free_slots(client: redis.Redis, user_id: int) -> None:
    """Forget finished tasks in the user's set; refuse when the set is full."""
    active = _key("active", user_id)
    for task_id in client.smembers(active):
        if AsyncResult(task_id.decode(), app=current_app).ready():
            client.srem(active, task_id)
    limit = settings.RACECRAFT_BACKGROUND_TASKS_PER_USER
    if client.scard(active) >= limit:
        raise ServiceError(
            f"you have {limit} imports or car exports under way, the most at once; "
            "wait for one to finish"
        )


def _send(client: redis.Redis, user_id: int, kind: str, name: str, kwargs: dict) -> str:
    """Queue task ``name`` for the user; its id is readable by them only."""
    task_id = uuid.uuid4().hex
    client.set(_key("owner", task_id), f"{user_id}:{kind}", ex=KEY_TTL_S)
    client.sadd(_key("active", user_id), task_id)
    client.expire(_key("active", user_id), KEY_TTL_S)
    try:
        current_app.send_task(name, kwargs=kwargs, task_id=task_id)
    except Exception as exc:  # noqa: BLE001 - a task that cannot be queued is refused
        log.warning("could not queue %s", name, exc_info=True)
        client.srem(_key("active", user_id), task_id)
        client.delete(_key("owner", task_id))
        raise ServiceError(QUEUE_DOWN) from exc
    return task_id


# ------------------------------------------------------------------------------ import
def model_import_start(*, owner, name: str, description: str, data: bytes) -> str:
    """Store the upload and queue its import; returns the task id. Raises ServiceError (a
    taken name, the quota, the per-user limit, the store or the queue unavailable)."""
    check_name(owner, name)
    check_model_quota(owner)
    client = _client()
    try:
        _free_slots(client, owner.pk)
        folder = f"{UPLOADS}{int(time.time())}-u{owner.pk}-{uuid.uuid4().hex}/"
        key = f"{folder}upload"
        try:
            get_store().put_bytes(key, data)
        except StoreError as exc:
            raise store_failure(exc, "the upload could not be stored") from None
        kwargs = {"owner_id": owner.pk, "name": name, "description": description,
                  "upload_key": key}  # fmt: skip
        try:
            return _send(client, owner.pk, "import", IMPORT_MODEL, kwargs)
        except (ServiceError, redis.RedisError):
            _forget_upload(key)
            raise
    except redis.RedisError as exc:  # Redis holds the limits and the queue: both unreachable
        log.warning("could not reach Redis for an import", exc_info=True)
        raise ServiceError(QUEUE_DOWN) from exc
    finally:
        client.close()


def _forget_upload(key: str) -> None:
    """Remove an upload (its folder: the store deletes folders, not single objects)."""
    try:
        get_store().delete_prefix(key.rsplit("/", 1)[0] + "/")
    except StoreError:
        log.warning("could not remove the upload %s", key, exc_info=True)


def uploads_prune(*, older_than_s: float = UPLOAD_MAX_AGE_S) -> int:
    """Remove uploads older than ``older_than_s`` (their import never ran: a task the broker
    lost, a worker killed mid-way). Folders are named ``<unix time>-u<user>-<id>/``. Returns
    how many were removed (beat runs this hourly)."""
    store, removed = get_store(), 0
    folders = {key[len(UPLOADS) :].split("/", 1)[0] for key in store.list(UPLOADS)}
    for folder in folders:
        stamp = folder.split("-", 1)[0]
        if stamp.isdigit() and time.time() - int(stamp) > older_than_s:
            store.delete_prefix(f"{UPLOADS}{folder}/")
            removed += 1
    return removed


def model_import_run(*, owner_id: int, name: str, description: str, upload_key: str) -> dict:
    """In the worker: import the stored upload (all or nothing), then remove it. The archive
    is read and converted in a bounded child process (see
    :func:`~training.services.model_imports.model_import`); the rows and store writes happen here.
    Every failure comes back as a sentence with its reason."""
    try:
        owner = get_user_model().objects.get(pk=owner_id)
        try:
            data = get_store().get_bytes(upload_key)
        except ObjectNotFound:
            raise ServiceError("the upload is gone from the store; upload it again") from None
        except StoreError as exc:
            raise store_failure(exc, "the upload could not be read") from None
        model = model_import(owner=owner, name=name, upload=data, description=description)
    except ServiceError as exc:
        return {"ok": False, "error": exc.sentence, "field": exc.field}
    except (RecursionError, MemoryError) as exc:  # in the worker itself, not the child
        log.warning("the import of %s failed", upload_key, exc_info=True)
        reason = "data nested too deeply" if isinstance(exc, RecursionError) else "out of memory"
        return {"ok": False, "error": f"The import failed ({reason}).", "field": "archive"}
    finally:
        _forget_upload(upload_key)
    note = getattr(model, "import_note", "")
    return {"ok": True, "model_id": model.pk, "name": model.name, "note": note}


# ------------------------------------------------------------------------------ car export
def car_export_ready(model: RacingModel) -> bytes | None:
    """The car archive when it is already built (a store read, nothing heavy), else None.
    An unreachable store is raised (the page answers 503)."""
    if not model.has_checkpoint:
        raise ServiceError("this model has no trained checkpoint yet")
    return car_archive_stored(model)


def car_export_start(*, model: RacingModel, user) -> str:
    """Queue building the model's car archive into the store, or follow the export of this
    model already under way; returns the task id."""
    if model.owner_id != user.pk:
        raise ServiceError("no such model")
    if not model.has_checkpoint:
        raise ServiceError("this model has no trained checkpoint yet")
    client = _client()
    try:
        running = client.get(_key("export", model.pk))
        if running and not AsyncResult(running.decode(), app=current_app).ready():
            return running.decode()
        _free_slots(client, user.pk)
        task_id = _send(client, user.pk, "export", EXPORT_CAR_MODEL, {"model_id": model.pk})
        client.set(_key("export", model.pk), task_id, ex=KEY_TTL_S)
        return task_id
    except redis.RedisError as exc:
        log.warning("could not reach Redis for a car export", exc_info=True)
        raise ServiceError(QUEUE_DOWN) from exc
    finally:
        client.close()


def car_export_run(*, model_id: int) -> dict:
    """In the worker: build the car archive into the store."""
    try:
        model = RacingModel.objects.get(pk=model_id)
    except RacingModel.DoesNotExist:
        return {"ok": False, "error": "The model was deleted.", "field": None}
    try:
        car_model_archive(model)
    except StoreUnavailable as exc:
        error = store_failure(exc, "the car model could not be saved")
        return {"ok": False, "error": error.sentence, "field": None}
    except ServiceError as exc:
        return {"ok": False, "error": exc.sentence, "field": None}
    return {"ok": True, "model_id": model.pk}


# ------------------------------------------------------------------------------ status
def background_status(*, user_id: int, task_id: str) -> BackgroundStatus:
    """Where the user's import or export ``task_id`` is; raises TaskNotFound for an id that
    is not theirs (or too old)."""
    client = _client()
    try:
        owner = client.get(_key("owner", task_id)) if isinstance(task_id, str) else None
        who, _, kind = (owner or b"").decode().partition(":")
        if who != str(user_id):
            raise TaskNotFound("no such task")
        result = AsyncResult(task_id, app=current_app)
        if not result.ready():
            return {"status": "running" if result.state == "STARTED" else "queued", "kind": kind}
        client.srem(_key("active", user_id), task_id)
    finally:
        client.close()
    answer: Any = result.result
    if result.successful() and isinstance(answer, dict):
        return {"status": "done", "kind": kind, **answer}
    log.warning("background task %s failed: %r", task_id, answer)
    return {"status": "done", "kind": kind, "ok": False, "field": None,
            "error": "The task could not finish; try again."}  # fmt: skip
