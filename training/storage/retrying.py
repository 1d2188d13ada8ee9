"""Any object store, with its calls retried while the store is unavailable."""

from __future__ import annotations

import logging
from typing import Any

from training.storage.base import OCTET_STREAM, ObjectStore, StoreUnavailable

_log = logging.getLogger(__name__)


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
