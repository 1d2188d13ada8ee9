"""The object store: models, checkpoints, logs and videos, in a local folder or in MinIO/S3.

Only :mod:`training.storage.s3` imports the minio SDK (house style, after healthchecks'
``hc/lib/s3.py``): :class:`MinioStore` builds its client lazily on first use and turns every
SDK, HTTP and OS error into one exception of ours, :class:`StoreError` (or
:class:`ObjectNotFound` for a missing key). :class:`LocalStore` keeps the same contract on disk.

Keys are ``/``-separated relative paths (``"42/model/model_metadata.json"``). Every key is
checked the same way on both backends (:func:`validate_key`): no absolute paths, no ``.`` or
``..`` segments, no backslashes, no empty segments, no control characters, so a key can never
leave the store. Prefixes passed to :meth:`ObjectStore.list` and
:meth:`ObjectStore.delete_prefix` are folders: ``"42"`` means everything under ``"42/"``.

The per-model layout (DeepRacer-for-Cloud names) is ``training.interchange.layout.ModelKeys``.

The rooms: base.py (errors, keys, the :class:`ObjectStore` interface, the bucket name rule),
local.py (:class:`LocalStore`), s3.py (:class:`MinioStore`; :func:`read_model_folder`, a
model folder out of someone else's bucket), retrying.py
(:class:`RetryingStore`), config.py (:func:`store_from_settings`).
"""

from __future__ import annotations

from training.storage.base import (
    BUCKET_PREFIX,
    DEFAULT_BUCKET,
    MAX_KEY_BYTES,
    OCTET_STREAM,
    BucketAccess,
    BucketError,
    ObjectNotFound,
    ObjectStore,
    StoreError,
    StoreUnavailable,
    check_bucket_name,
    validate_key,
)
from training.storage.config import store_from_settings
from training.storage.local import LocalStore
from training.storage.retrying import RetryingStore
from training.storage.s3 import MinioStore, read_model_folder

__all__ = [
    "BUCKET_PREFIX",
    "DEFAULT_BUCKET",
    "MAX_KEY_BYTES",
    "OCTET_STREAM",
    "BucketAccess",
    "BucketError",
    "LocalStore",
    "MinioStore",
    "ObjectNotFound",
    "ObjectStore",
    "RetryingStore",
    "StoreError",
    "StoreUnavailable",
    "check_bucket_name",
    "read_model_folder",
    "store_from_settings",
    "validate_key",
]
