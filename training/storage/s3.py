"""The object store in MinIO (or any S3 server): the only module that imports the minio SDK.

After healthchecks' ``hc/lib/s3.py``: :class:`MinioStore` builds its client lazily on first use
(importing minio only then, so a process that never talks to MinIO never loads the SDK) and
turns every SDK, HTTP and OS error into one exception of ours, :class:`StoreError`
(:class:`StoreUnavailable` for a failure that may pass, :class:`ObjectNotFound` for a missing
key).

:func:`read_model_folder` reads a model folder out of someone else's bucket (a
DeepRacer-for-Cloud prefix, for an import) with keys that are used once and never kept. It does
not use the minio SDK: a user names that server, so it is read through the guarded outbound
client (:mod:`training.storage.outbound`, :mod:`training.storage.foreign_s3`).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from training.storage.base import (
    DEFAULT_BUCKET,
    OCTET_STREAM,
    BucketAccess,
    BucketError,
    ObjectNotFound,
    ObjectStore,
    StoreError,
    StoreUnavailable,
    _folder,
    check_bucket_name,
    validate_key,
)
from training.storage.foreign_s3 import ForeignBucket, S3Refusal
from training.storage.outbound import Endpoint, OutboundError, OutboundPolicy, OutboundSession


class MinioStore(ObjectStore):
    """Objects in one bucket of a MinIO (or any S3) server, through the minio SDK.

    ``endpoint`` is ``host:port`` (a leading ``http://``/``https://`` is accepted and stripped);
    ``bucket`` must start with ``"deepracer"`` (DeepRacer tools only read such buckets) and be
    a valid S3 name, else :class:`StoreError` at construction. The client is built, and the
    bucket created when missing, on first use. ``timeout`` is seconds per HTTP request.
    """

    def __init__(
        self,
        endpoint: str,
        access_key: str,
        secret_key: str,
        secure: bool = False,
        bucket: str = DEFAULT_BUCKET,
        region: str | None = None,
        *,
        timeout: float = 30.0,
        retries: int = 3,
    ) -> None:
        check_bucket_name(bucket)
        for scheme in ("http://", "https://"):
            if endpoint.startswith(scheme):
                endpoint = endpoint[len(scheme) :]
        if not endpoint or "/" in endpoint.rstrip("/"):
            raise StoreError(f"MinIO endpoint must be host:port, not {endpoint!r}")
        self.endpoint = endpoint.rstrip("/")
        self.bucket = bucket
        self.secure = secure
        self.region = region or None
        self._credentials = (access_key, secret_key)
        self._timeout = timeout
        self._retries = retries
        self._client: Any = None

    def __repr__(self) -> str:
        scheme = "https" if self.secure else "http"
        return f"MinioStore({scheme}://{self.endpoint}/{self.bucket})"

    @property
    def client(self) -> Any:
        """The minio client, built (and the bucket ensured) on first use."""
        if self._client is None:
            import urllib3
            from minio import Minio

            http = urllib3.PoolManager(
                timeout=urllib3.Timeout(connect=min(self._timeout, 10.0), read=self._timeout),
                retries=urllib3.Retry(
                    total=self._retries,
                    backoff_factor=0.2,
                    status_forcelist=(500, 502, 503, 504),
                ),
            )
            client = Minio(
                self.endpoint,
                access_key=self._credentials[0],
                secret_key=self._credentials[1],
                secure=self.secure,
                region=self.region,
                http_client=http,
            )
            with self._errors("create bucket", self.bucket):
                if not client.bucket_exists(self.bucket):
                    client.make_bucket(self.bucket, location=self.region)
            self._client = client
        return self._client

    @contextmanager
    def _errors(self, action: str, key: str) -> Iterator[None]:
        from minio.error import MinioException, S3Error
        from urllib3.exceptions import HTTPError

        try:
            yield
        except StoreError:
            raise
        except S3Error as exc:
            if exc.code in ("NoSuchKey", "NoSuchObject", "ResourceNotFound"):
                raise ObjectNotFound(key) from exc
            kind = StoreUnavailable if exc.code in _TRANSIENT_S3_CODES else StoreError
            raise kind(
                f"cannot {action} {key!r}: {exc.code}: {exc.message}",
                action=action, key=key, reason=exc.code,
            ) from exc  # fmt: skip
        except (MinioException, HTTPError, OSError) as exc:
            # Unreachable, timed out, reset, or a 5xx without an S3 error body.
            raise StoreUnavailable(
                f"cannot {action} {key!r} at {self!r}: {exc}", action=action, key=key
            ) from exc
        except ValueError as exc:
            raise StoreError(
                f"cannot {action} {key!r} at {self!r}: {exc}", action=action, key=key
            ) from exc

    def put_bytes(self, key: str, data: bytes, content_type: str = OCTET_STREAM) -> None:
        validate_key(key)
        data = bytes(data)
        with self._errors("write", key):
            self.client.put_object(
                self.bucket, key, io.BytesIO(data), len(data), content_type=content_type
            )

    def get_bytes(self, key: str) -> bytes:
        validate_key(key)
        with self._errors("read", key):
            response = self.client.get_object(self.bucket, key)
            try:
                return response.read()
            finally:
                response.close()
                response.release_conn()

    def exists(self, key: str) -> bool:
        validate_key(key)
        try:
            with self._errors("stat", key):
                self.client.stat_object(self.bucket, key)
        except ObjectNotFound:
            return False
        return True

    def stat_size(self, key: str) -> int:
        validate_key(key)
        with self._errors("read", key):
            return int(self.client.stat_object(self.bucket, key).size)

    def get_range(self, key: str, start: int, length: int) -> bytes:
        validate_key(key)
        if length <= 0:
            return b""
        with self._errors("read", key):
            response = self.client.get_object(self.bucket, key, offset=max(0, start),
                                              length=length)  # fmt: skip
            try:
                return response.read()
            finally:
                response.close()
                response.release_conn()

    def list(self, prefix: str = "") -> list[str]:
        folder = _folder(prefix, allow_root=True)
        with self._errors("list", folder):
            objects = self.client.list_objects(self.bucket, prefix=folder or None, recursive=True)
            return sorted(obj.object_name for obj in objects if not obj.is_dir)

    def delete_prefix(self, prefix: str) -> int:
        from minio.deleteobjects import DeleteObject

        folder = _folder(prefix, allow_root=False)
        keys = self.list(folder)
        with self._errors("delete", folder):
            for start in range(0, len(keys), 1000):  # S3 deletes at most 1000 per request
                batch = [DeleteObject(k) for k in keys[start : start + 1000]]
                failures = list(self.client.remove_objects(self.bucket, batch))
                if failures:
                    raise StoreError(f"cannot delete {failures[0].name!r}: {failures[0].message}")
        return len(keys)


_TRANSIENT_S3_CODES = frozenset(
    {"InternalError", "ServiceUnavailable", "SlowDown", "RequestTimeout", "RequestTimeTooSkewed",
     "XMinioServerNotInitialized", "XMinioStorageFull"}
)  # fmt: skip


# ------------------------------------------------------------------------- someone's bucket
FileReader = Callable[[Iterable[str]], dict[str, bytes]]
FileChooser = Callable[[Mapping[str, int], FileReader], Iterable[str]]
"""``choose(sizes, read)``: which files of a folder to fetch, from their sizes (relative path →
bytes) and, when it needs them, the content of a few small ones (``read(paths)``)."""

#: The folders of a model prefix listed (never recursively): its top, ``model/``, ``ip/``. A
#: DeepRacer-for-Cloud prefix also holds logs (``training-simtrace/``, ``metrics/``...), never
#: listed nor read.
MODEL_FOLDERS = ("", "model/", "ip/")
_DENIED = {
    "InvalidAccessKeyId": "access_key",
    "SignatureDoesNotMatch": "secret_key",
    "AccessDenied": "denied",
    "AllAccessDisabled": "denied",
    "AccountProblem": "denied",
}
_NO_BUCKET = ("NoSuchBucket", "InvalidBucketName")


def read_model_folder(
    access: BucketAccess,
    choose: FileChooser,
    *,
    max_files: int,
    max_bytes: int,
    policy: OutboundPolicy,
) -> dict[str, bytes]:
    """The files of the model folder ``access`` names that ``choose`` wants, relative path →
    bytes. Only :data:`MODEL_FOLDERS` are listed, each up to ``max_files`` objects; the files
    fetched may hold ``max_bytes`` in all. Everything goes through one guarded
    :class:`~training.storage.outbound.OutboundSession` under ``policy`` (the addresses it
    may reach, its deadline, its number of requests, each body's bound). Raises
    :class:`BucketError` (its ``reason`` says which failure: ``unreachable`` for every failure
    to reach an S3 server, whatever the server sent), never with the keys or the server's
    words in it."""
    if access.prefix:
        try:
            validate_key(access.prefix)
        except StoreError as exc:
            raise BucketError(f"not a folder name: {exc}", reason="prefix") from None
    try:
        endpoint = Endpoint.parse(access.endpoint, secure=access.secure)
    except ValueError:
        raise BucketError(f"the endpoint must be host:port, not {access.endpoint!r}",
                          reason="endpoint") from None  # fmt: skip
    base = f"{access.prefix}/" if access.prefix else ""
    sizes: dict[str, int] = {}
    with OutboundSession(endpoint, policy) as session, _bucket_errors(access, endpoint):
        bucket = ForeignBucket(session, access.bucket, access, access.region)
        for folder in MODEL_FOLDERS:
            for listed, (key, size) in enumerate(bucket.list_folder(base + folder), start=1):
                if listed > max_files:
                    raise BucketError(f"{access.url}/{folder} holds more than {max_files} files",
                                      reason="too_big")  # fmt: skip
                sizes[key[len(base) :]] = size
        fetched: dict[str, bytes] = {}

        def read(names: Iterable[str]) -> dict[str, bytes]:
            wanted = [n for n in dict.fromkeys(names) if n in sizes]
            total = sum(sizes[n] for n in {*fetched, *wanted})
            if total > max_bytes:
                size = f"{max_bytes / 2**20:.0f} MB"
                raise BucketError(f"the model at {access.url} is larger than {size}",
                                  reason="too_big")  # fmt: skip
            for name in wanted:
                if name not in fetched:
                    fetched[name] = _read_object(bucket, base + name, sizes[name])
            return {n: fetched[n] for n in wanted}

        return read(choose(sizes, read))


def _read_object(bucket: ForeignBucket, key: str, size: int) -> bytes:
    return bucket.read(key, size)


@contextmanager
def _bucket_errors(access: BucketAccess, endpoint: Endpoint) -> Iterator[None]:
    """A known S3 refusal as a :class:`BucketError` on its reason, every other failure as
    ``unreachable``; the detail logged is ours (which rule), never the server's words."""
    try:
        yield
    except StoreError:
        raise
    except S3Refusal as refusal:
        reason = _DENIED.get(
            refusal.code, "bucket" if refusal.code in _NO_BUCKET else "unreachable"
        )
        raise BucketError(f"{access.url} at {endpoint}: {refusal.code}", action="read",
                          key=access.prefix, reason=reason) from None  # fmt: skip
    except OutboundError as exc:
        raise BucketError(f"cannot reach {endpoint}: {exc.detail}",
                          reason="unreachable") from None  # fmt: skip
