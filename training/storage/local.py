"""The object store in a local folder: objects as files, written atomically."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from training.storage.base import (
    _TMP_DIR,
    OCTET_STREAM,
    ObjectNotFound,
    ObjectStore,
    StoreError,
    _folder,
    validate_key,
)


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
