"""The object store's bucket name, for Django settings: the default and the check DeepRacer's
tools need (a ``deepracer*`` S3 name). Django-free and light: it loads no minio SDK
(training.storage builds a MinIO client only when a MinIO store is made) and no sandbox, so
settings stay quick to import. The rules themselves live in :mod:`training.storage`."""

from __future__ import annotations

from training.storage import DEFAULT_BUCKET, StoreError, check_bucket_name

__all__ = ["DEFAULT_BUCKET", "StoreError", "check_bucket_name"]
