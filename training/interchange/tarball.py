"""Deterministic tar.gz archives: names sorted, relative (checked like store keys), mtime
fixed, owner 0/0, mode 0644, gzip header without name or time."""

from __future__ import annotations

import gzip
import io
import tarfile
from collections.abc import Mapping

from training.storage import StoreError, validate_key

ARCHIVE_MTIME = 1_543_363_200  # 2018-11-28, DeepRacer's launch; any fixed value works


class ExportError(ValueError):
    """A model that cannot be exported or archived."""


def deterministic_tar_gz(files: Mapping[str, bytes]) -> bytes:
    """A tar.gz of ``files`` (relative name → bytes) that is byte-for-byte reproducible."""
    return gzip.compress(deterministic_tar(files), compresslevel=6, mtime=0)


def deterministic_tar(files: Mapping[str, bytes]) -> bytes:
    """:func:`deterministic_tar_gz` uncompressed (weights hardly compress; no time spent)."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for name in sorted(files):
            try:
                validate_key(name)
            except StoreError as exc:
                raise ExportError(f"bad archive member name: {exc}") from None
            data = bytes(files[name])
            info = tarfile.TarInfo(name)
            info.size, info.mtime, info.mode = len(data), ARCHIVE_MTIME, 0o644
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            tar.addfile(info, io.BytesIO(data))
    return raw.getvalue()
