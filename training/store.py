"""The object store configured in Django settings (MinIO, or a local folder by default)."""

from __future__ import annotations

from django.conf import settings

from training.interchange.layout import ModelKeys
from training.storage import ObjectStore, store_from_settings

_cache: dict[tuple, ObjectStore] = {}


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
        store = store_from_settings(config)
        _cache[key] = store
    return store


def keys_for(model_id: int) -> ModelKeys:
    """The object keys of model ``model_id``, under its folder (``RacingModel.store_folder``:
    ``u<owner>-<name>`` for new models, the id for models stored before that)."""
    from training.models import RacingModel

    prefix = RacingModel.objects.filter(pk=model_id).values_list("store_prefix", flat=True).first()
    return ModelKeys(prefix or str(model_id))
