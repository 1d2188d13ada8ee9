"""The object store configured in Django settings (MinIO, or a local folder by default),
retried on transient errors: for ``RACECRAFT_STORE_RETRY_S`` seconds in the web server (a
request then answers "storage unavailable, try again"), for ``RACECRAFT_STORE_WORKER_RETRY_S``
in Celery workers (:func:`use_worker_retries`), so a checkpoint written after hours of training
outlives a store outage."""

from __future__ import annotations

from django.conf import settings

from training.interchange.layout import ModelKeys
from training.storage import ObjectStore, RetryingStore, store_from_settings

_cache: dict[tuple, ObjectStore] = {}
_patience = {"worker": False}


def use_worker_retries(enabled: bool = True) -> None:
    """This process is a worker: retry store calls for ``RACECRAFT_STORE_WORKER_RETRY_S``."""
    _patience["worker"] = enabled


def retry_seconds() -> float:
    """How long this process retries a store call that failed transiently."""
    if _patience["worker"]:
        return float(getattr(settings, "RACECRAFT_STORE_WORKER_RETRY_S", 120.0))
    return float(getattr(settings, "RACECRAFT_STORE_RETRY_S", 3.0))


def get_store() -> ObjectStore:
    """The store for the current settings (built once per distinct configuration)."""
    config = {
        "MINIO_ENDPOINT": settings.MINIO_ENDPOINT,
        "MINIO_ACCESS_KEY": settings.MINIO_ACCESS_KEY,
        "MINIO_SECRET_KEY": settings.MINIO_SECRET_KEY,
        "MINIO_SECURE": settings.MINIO_SECURE,
        "MINIO_BUCKET": settings.MINIO_BUCKET,
        "STORE_DIR": str(settings.STORE_DIR),
    }
    key = tuple(sorted(config.items()))
    store = _cache.get(key)
    if store is None:
        store = RetryingStore(store_from_settings(config), retry_s=retry_seconds)
        _cache[key] = store
    return store


def keys_for(model_id: int) -> ModelKeys:
    """The object keys of model ``model_id``, under its folder (``RacingModel.store_folder``:
    ``u<owner>-<name>`` for new models, the id for models stored before that)."""
    from training.models import RacingModel

    prefix = RacingModel.objects.filter(pk=model_id).values_list("store_prefix", flat=True).first()
    return ModelKeys(prefix or str(model_id))
