"""The object store: models, checkpoints, logs and videos, in a local folder or in MinIO/S3.

This is the only module that imports the minio SDK (house style, after healthchecks'
``hc/lib/s3.py``): :class:`MinioStore` builds its client lazily on first use and turns every
SDK, HTTP and OS error into one exception of ours, :class:`StoreError` (or
:class:`ObjectNotFound` for a missing key). :class:`LocalStore` keeps the same contract on disk.

Keys are ``/``-separated relative paths (``"42/model/model_metadata.json"``). Every key is
checked the same way on both backends (:func:`validate_key`): no absolute paths, no ``.`` or
``..`` segments, no backslashes, no empty segments, no control characters, so a key can never
leave the store. Prefixes passed to :meth:`ObjectStore.list` and
:meth:`ObjectStore.delete_prefix` are folders: ``"42"`` means everything under ``"42/"``.

The per-model layout (DeepRacer-for-Cloud names) is ``training.interchange.layout.ModelKeys``.
"""

from __future__ import annotations

import io
import logging
import os
import re
import shutil
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

_log = logging.getLogger(__name__)
BUCKET_PREFIX = "deepracer"
DEFAULT_BUCKET = "deepracer-models"
MAX_KEY_BYTES = 1024  # S3's limit on an object key
OCTET_STREAM = "application/octet-stream"
_TMP_DIR = ".racecraft-tmp"  # LocalStore's staging folder for atomic writes (never a key)
_BUCKET_RE = re.compile(r"^[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]$")


class StoreError(Exception):
    """Any failure of the object store (bad key, unreachable server, refused request...).

    The message is for the log: it may name the server and the whole key. What a user may
    read is :meth:`public_message`: the object's file name and the reason, never an endpoint,
    a bucket or a folder."""

    def __init__(self, message: str, *, action: str = "", key: str = "", reason: str = "") -> None:
        super().__init__(message)
        self.action, self.key, self.reason = action, key, reason

    def public_message(self) -> str:
        if isinstance(self, StoreUnavailable):
            return "the model store is unavailable right now; try again in a minute"
        if self.action and self.key:
            name = self.key.rstrip("/").rsplit("/", 1)[-1]
            return f"the model store could not {self.action} {name}" + (
                f": {self.reason}" if self.reason else ""
            )
        return "the model store refused the request"


class StoreUnavailable(StoreError):
    """A failure that may pass: the server is unreachable, timed out or answered 5xx. Worth
    retrying (:class:`RetryingStore` does); a user is told to try again."""


class ObjectNotFound(StoreError):
    """The key holds no object; ``key`` names it."""

    def __init__(self, key: str) -> None:
        super().__init__(f"no object at {key!r}", action="find", key=key, reason="missing")


def validate_key(key: str) -> str:
    """Return ``key`` if it is a safe relative object key, else raise :class:`StoreError`."""
    if not isinstance(key, str) or not key:
        raise StoreError(f"an object key must be a non-empty string, not {key!r}")
    if len(key.encode("utf-8", "surrogatepass")) > MAX_KEY_BYTES:
        raise StoreError(f"object key is longer than {MAX_KEY_BYTES} bytes")
    if key.startswith("/"):
        raise StoreError(f"object key {key!r} must be relative, not absolute")
    if "\\" in key:
        raise StoreError(f"object key {key!r} must not contain backslashes")
    if any(ord(c) < 32 or ord(c) == 127 for c in key):
        raise StoreError(f"object key {key!r} must not contain control characters")
    for segment in key.split("/"):
        if segment == "":
            raise StoreError(f"object key {key!r} has an empty segment")
        if segment in (".", ".."):
            raise StoreError(f"object key {key!r} must not contain '.' or '..' segments")
    if key.split("/")[0] == _TMP_DIR:
        raise StoreError(f"object key {key!r} uses a reserved folder")
    return key


def _folder(prefix: str, *, allow_root: bool) -> str:
    """A validated folder prefix ending with ``/`` (``""`` is the whole store if allowed)."""
    if prefix in ("", "/") and allow_root:
        return ""
    return validate_key(prefix.rstrip("/")) + "/"


class ObjectStore(ABC):
    """What the rest of Racecraft may do with stored objects. Keys: see :func:`validate_key`.

    Every method raises :class:`StoreError` on failure; reads of a missing key raise
    :class:`ObjectNotFound`. Deleting a folder that holds nothing is not an error.
    """

    @abstractmethod
    def put_bytes(self, key: str, data: bytes, content_type: str = OCTET_STREAM) -> None:
        """Store ``data`` at ``key``, replacing any previous object atomically."""

    @abstractmethod
    def get_bytes(self, key: str) -> bytes:
        """The whole object at ``key``."""

    @abstractmethod
    def exists(self, key: str) -> bool:
        """Whether an object is stored at ``key``."""

    @abstractmethod
    def stat_size(self, key: str) -> int:
        """The size of the object at ``key``, bytes."""

    @abstractmethod
    def get_range(self, key: str, start: int, length: int) -> bytes:
        """``length`` bytes of the object at ``key`` from byte ``start`` (fewer at its end):
        a video is served by ranges without reading the whole object."""

    @abstractmethod
    def list(self, prefix: str = "") -> list[str]:
        """Every key under the folder ``prefix`` (recursively), sorted; ``""`` lists all."""

    @abstractmethod
    def delete_prefix(self, prefix: str) -> int:
        """Remove every object under the folder ``prefix`` (never the whole store).

        Returns how many objects were removed.
        """


class LocalStore(ObjectStore):
    """Objects as files under ``root`` (created when missing). Writes go to a temporary file
    in ``root/.racecraft-tmp`` and are renamed into place, so readers never see half a file."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root).resolve()
        try:
            (self.root / _TMP_DIR).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot create the store folder {self.root}: {exc}") from exc

    def __repr__(self) -> str:
        return f"LocalStore({str(self.root)!r})"

    def _path(self, key: str) -> Path:
        path = self.root / validate_key(key)
        # Defence in depth: a symlink planted inside the store must not lead out of it.
        if not path.resolve().is_relative_to(self.root):
            raise StoreError(f"object key {key!r} leads outside the store")
        return path

    @contextmanager
    def _errors(self, action: str, key: str) -> Iterator[None]:
        try:
            yield
        except StoreError:
            raise
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError) as exc:
            if action == "read":
                raise ObjectNotFound(key) from exc
            raise StoreError(
                f"cannot {action} {key!r}: {exc.strerror or exc}",
                action=action, key=key, reason=exc.strerror or "",
            ) from exc  # fmt: skip
        except OSError as exc:
            raise StoreError(
                f"cannot {action} {key!r}: {exc.strerror or exc}",
                action=action, key=key, reason=exc.strerror or "",
            ) from exc  # fmt: skip

    def _write_atomic(self, path: Path, write: Any) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.root / _TMP_DIR, prefix="put-")
        try:
            with os.fdopen(fd, "wb") as handle:
                write(handle)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, path)
        except BaseException:
            with suppress(OSError):
                os.unlink(tmp)
            raise

    def put_bytes(self, key: str, data: bytes, content_type: str = OCTET_STREAM) -> None:
        path = self._path(key)
        with self._errors("write", key):
            self._write_atomic(path, lambda handle: handle.write(bytes(data)))

    def get_bytes(self, key: str) -> bytes:
        path = self._path(key)
        with self._errors("read", key):
            return path.read_bytes()

    def exists(self, key: str) -> bool:
        return self._path(key).is_file()

    def stat_size(self, key: str) -> int:
        path = self._path(key)
        with self._errors("read", key):
            if not path.is_file():
                raise FileNotFoundError(key)
            return path.stat().st_size

    def get_range(self, key: str, start: int, length: int) -> bytes:
        path = self._path(key)
        with self._errors("read", key), path.open("rb") as handle:
            handle.seek(max(0, start))
            return handle.read(max(0, length))

    def list(self, prefix: str = "") -> list[str]:
        folder = _folder(prefix, allow_root=True)
        base = self._path(folder.rstrip("/")) if folder else self.root
        if not base.is_dir():
            return []
        keys = []
        for dirpath, dirnames, filenames in os.walk(base):
            if Path(dirpath) == self.root and _TMP_DIR in dirnames:
                dirnames.remove(_TMP_DIR)
            rel = Path(dirpath).relative_to(self.root).as_posix()
            keys += [name if rel == "." else f"{rel}/{name}" for name in filenames]
        return sorted(keys)

    def delete_prefix(self, prefix: str) -> int:
        folder = _folder(prefix, allow_root=False)
        count = len(self.list(folder))
        base = self._path(folder.rstrip("/"))
        with self._errors("delete", folder):
            if base.is_dir():
                shutil.rmtree(base)
                self._prune(base.parent)
        return count

    def _prune(self, folder: Path) -> None:
        """Remove now-empty folders between ``folder`` and the root (tidy, like S3)."""
        while folder != self.root and folder.is_relative_to(self.root):
            try:
                folder.rmdir()
            except OSError:
                return
            folder = folder.parent


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


class RetryingStore(ObjectStore):
    """Another store, with every call retried on :class:`StoreUnavailable` (exponential
    backoff from ``first_wait_s`` up to ``max_wait_s`` between tries) until ``retry_s()``
    seconds have passed since the first try; then the last error is raised. Other errors
    (missing keys, bad keys, a full disk) are raised at once. ``retry_s`` is a callable so the
    patience can differ by process: a web request gives up in seconds, a training job that ran
    for hours waits out a store outage of minutes (training/store.py sets it)."""

    def __init__(
        self,
        inner: ObjectStore,
        retry_s: Any = 5.0,
        *,
        first_wait_s: float = 0.2,
        max_wait_s: float = 5.0,
        sleep: Any = None,
        clock: Any = None,
    ) -> None:
        import time

        self.inner = inner
        self._retry_s = retry_s if callable(retry_s) else (lambda: float(retry_s))
        self._first_wait_s = first_wait_s
        self._max_wait_s = max_wait_s
        self._sleep = sleep or time.sleep
        self._clock = clock or time.monotonic

    def __repr__(self) -> str:
        return repr(self.inner)

    def _call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        deadline = self._clock() + max(0.0, float(self._retry_s()))
        wait = self._first_wait_s
        while True:
            try:
                return getattr(self.inner, method)(*args, **kwargs)
            except StoreUnavailable as exc:
                left = deadline - self._clock()
                if left <= 0:
                    raise
                if wait == self._first_wait_s:
                    _log.warning("store unavailable (%s); retrying for up to %.0f s", exc, left)
                self._sleep(min(wait, left))
                wait = min(wait * 2, self._max_wait_s)

    def put_bytes(self, key: str, data: bytes, content_type: str = OCTET_STREAM) -> None:
        self._call("put_bytes", key, data, content_type)

    def get_bytes(self, key: str) -> bytes:
        return self._call("get_bytes", key)

    def exists(self, key: str) -> bool:
        return self._call("exists", key)

    def stat_size(self, key: str) -> int:
        return self._call("stat_size", key)

    def get_range(self, key: str, start: int, length: int) -> bytes:
        return self._call("get_range", key, start, length)

    def list(self, prefix: str = "") -> list[str]:
        return self._call("list", prefix)

    def delete_prefix(self, prefix: str) -> int:
        return self._call("delete_prefix", prefix)


def check_bucket_name(bucket: str) -> str:
    """Return ``bucket`` if DeepRacer tools can use it, else raise :class:`StoreError`.

    The name must start with ``"deepracer"`` (DeepRacer tools only read such buckets) and be a
    valid S3 name: 3-63 lowercase letters, digits, dots or hyphens, a letter or digit at both
    ends, no ``..``. The settings check ``MINIO_BUCKET`` with it too.
    """
    if not isinstance(bucket, str) or not bucket.startswith(BUCKET_PREFIX):
        raise StoreError(
            f"bucket {bucket!r} must start with {BUCKET_PREFIX!r} "
            f"(DeepRacer tools only read buckets named {BUCKET_PREFIX}*)"
        )
    if not _BUCKET_RE.match(bucket) or ".." in bucket:
        raise StoreError(
            f"bucket {bucket!r} is not a valid bucket name "
            "(3-63 lowercase letters, digits, dots or hyphens)"
        )
    return bucket


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
