"""What every object store shares: the errors, the key rules and the :class:`ObjectStore`
interface; the bucket name rule too (the settings check ``MINIO_BUCKET`` with it)."""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

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


@dataclass(frozen=True)
class BucketAccess:
    """A folder of someone else's bucket (a DeepRacer-for-Cloud model prefix) and the keys to
    read it, for one read (:func:`training.storage.s3.read_model_folder`); never kept.

    ``endpoint`` is ``host[:port]``; a leading ``http://`` or ``https://`` decides ``secure``.
    ``prefix`` has no leading or trailing ``/`` (``""``: the bucket's top). The keys are left
    out of ``repr`` (so out of tracebacks' locals and logs); ``url`` names the folder without
    them.
    """

    endpoint: str
    bucket: str
    prefix: str
    access_key: str = field(repr=False)
    secret_key: str = field(repr=False)
    secure: bool = True
    region: str = ""

    @property
    def url(self) -> str:
        return f"s3://{self.bucket}/{self.prefix}" if self.prefix else f"s3://{self.bucket}"


class BucketError(StoreError):
    """Reading someone else's bucket failed; ``reason`` says how, for the caller to word it
    and place it: ``endpoint`` (not a ``host:port``), ``unreachable`` (refused, unknown host,
    timed out, not an S3 server), ``access_key`` (unknown key), ``secret_key`` (wrong secret),
    ``denied`` (the keys may not read this bucket), ``bucket`` (no such bucket or a bad
    name), ``prefix`` (a bad folder name), ``too_big`` (over the bounds) or ``refused``
    (another S3 error). The message never holds the keys."""
