"""The object store the settings ask for: MinIO or a local folder."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from training.storage.base import DEFAULT_BUCKET, ObjectStore, StoreError
from training.storage.local import LocalStore
from training.storage.s3 import MinioStore


def _flag(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("1", "true", "yes", "on"):
        return True
    if text in ("", "0", "false", "no", "off", "none"):
        return False
    raise StoreError(f"MINIO_SECURE must be true or false, not {value!r}")


def store_from_settings(settings: Mapping[str, Any]) -> ObjectStore:
    """The store the settings ask for: MinIO when ``MINIO_ENDPOINT`` is set (with
    ``MINIO_ACCESS_KEY``, ``MINIO_SECRET_KEY``, ``MINIO_SECURE``, ``MINIO_BUCKET`` and an
    optional ``MINIO_REGION``), else a :class:`LocalStore` at ``STORE_DIR``.

    ``settings`` is a plain mapping (e.g. built from Django settings by the caller). Raises
    :class:`StoreError` for an incomplete or invalid configuration.
    """
    endpoint = settings.get("MINIO_ENDPOINT") or ""
    if endpoint:
        access, secret = settings.get("MINIO_ACCESS_KEY"), settings.get("MINIO_SECRET_KEY")
        if not access or not secret:
            raise StoreError("MINIO_ENDPOINT is set: MINIO_ACCESS_KEY and MINIO_SECRET_KEY too")
        secure = settings.get("MINIO_SECURE")
        if secure is None or secure == "":
            secure = str(endpoint).startswith("https://")
        return MinioStore(
            str(endpoint),
            str(access),
            str(secret),
            secure=_flag(secure),
            bucket=str(settings.get("MINIO_BUCKET") or DEFAULT_BUCKET),
            region=settings.get("MINIO_REGION") or None,
        )
    store_dir = settings.get("STORE_DIR")
    if not store_dir:
        raise StoreError("set MINIO_ENDPOINT or STORE_DIR")
    return LocalStore(store_dir)
