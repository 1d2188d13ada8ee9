"""The result of a bounded import, as the child writes it and the worker reads it back.

No pickle: a fixed magic line, an 8-byte big-endian header length, a JSON header (the
metadata and hyperparameters as their JSON files, the reward function's text, the names and
sizes of the byte blobs), then the blobs (the re-saved checkpoint, the archive's data files)
one after the other. The reader bounds the header, checks that the blobs' sizes add up to
what follows, reads each blob once, and validates the metadata and hyperparameters again with
the same parsers an upload goes through. A failed import is a header with ``ok: false``, the
message and its reason (``archive``, ``memory``).
"""

from __future__ import annotations

import json
import os
from typing import BinaryIO

from training.interchange.archive import ArchiveError, ImportedModel
from training.interchange.deepracer import ImportedDeepRacerModel
from training.rl.hyperparams import HyperparameterError, parse_hyperparameters
from training.rl.metadata import MetadataError, ModelMetadata

MAGIC = b"racecraft-import/1\n"
MAX_HEADER_BYTES = 16 * 1024 * 1024
CHECKPOINT_BLOB = "checkpoint"
EXTRA_PREFIX = "extra/"


class WireError(ValueError):
    """A result file that is not what the child writes (a bug, never the user's fault)."""


def _write_header(out: BinaryIO, header: dict) -> None:
    text = json.dumps(header, ensure_ascii=True).encode()
    out.write(MAGIC + len(text).to_bytes(8, "big") + text)


def write_error(out: BinaryIO, message: str, reason: str) -> None:
    """A failed import: ``reason`` is ``archive`` (the upload's fault) or ``memory``."""
    _write_header(out, {"ok": False, "error": message[:2000], "reason": reason})


def write_result(out: BinaryIO, imported: ImportedModel | ImportedDeepRacerModel) -> None:
    """An imported model: the header, then its checkpoint and data files."""
    deepracer = isinstance(imported, ImportedDeepRacerModel)
    blobs = [(CHECKPOINT_BLOB, imported.checkpoint_bytes)]
    blobs += [(EXTRA_PREFIX + name, data) for name, data in imported.extra_files.items()]
    hyperparameters = imported.hyperparameters
    _write_header(
        out,
        {
            "ok": True,
            "kind": "deepracer" if deepracer else "racecraft",
            "metadata": imported.metadata.to_json(),
            "hyperparameters": hyperparameters.to_json() if hyperparameters else None,
            "reward_function": imported.reward_function,
            "checkpoint_name": imported.checkpoint_name,
            "source": imported.source if deepracer else None,
            "value_head_fresh": imported.value_head_fresh if deepracer else None,
            "blobs": [[name, len(data)] for name, data in blobs],
        },
    )
    for _, data in blobs:
        out.write(data)


def _header(handle: BinaryIO, size: int) -> dict:
    start = handle.read(len(MAGIC) + 8)
    if len(start) < len(MAGIC) + 8 or not start.startswith(MAGIC):
        raise WireError("the import's result has no header")
    length = int.from_bytes(start[len(MAGIC) :], "big")
    if length > min(MAX_HEADER_BYTES, size):
        raise WireError(f"the import's result header is {length:,} bytes")
    try:
        header = json.loads(handle.read(length))
    except (ValueError, RecursionError) as exc:
        raise WireError(f"the import's result header is not JSON ({exc})") from None
    if not isinstance(header, dict):
        raise WireError("the import's result header is not an object")
    return header


def _blobs(handle: BinaryIO, header: dict, left: int) -> dict[str, bytes]:
    listed = header.get("blobs")
    if not isinstance(listed, list) or not all(
        isinstance(b, list) and len(b) == 2 and isinstance(b[0], str) and isinstance(b[1], int)
        for b in listed
    ):
        raise WireError("the import's result lists no blobs")
    if any(size < 0 for _, size in listed) or sum(size for _, size in listed) != left:
        raise WireError("the import's result blobs do not add up to its size")
    blobs = {}
    for name, size in listed:
        blobs[name] = handle.read(size)
        if len(blobs[name]) != size:
            raise WireError("the import's result is truncated")
    return blobs


def read_result(path: str) -> ImportedModel | ImportedDeepRacerModel:
    """The model the child wrote at ``path`` (its size bounded by the caller). Raises
    :class:`ArchiveError` with the child's message for a refused upload, :class:`MemoryError`
    when the child ran out of memory, :class:`WireError` for a malformed result."""
    size = os.path.getsize(path)
    with open(path, "rb") as handle:
        header = _header(handle, size)
        if header.get("ok") is not True:
            message = str(header.get("error") or "the import failed")
            if header.get("reason") == "memory":
                raise MemoryError(message)
            raise ArchiveError(message)
        blobs = _blobs(handle, header, size - handle.tell())
    try:
        metadata = ModelMetadata.from_json(header.get("metadata"))
        raw = header.get("hyperparameters")
        hyperparameters = (
            parse_hyperparameters(raw, metadata.training_algorithm) if raw is not None else None
        )
    except (MetadataError, HyperparameterError) as exc:
        raise WireError(f"the import's result has bad metadata ({exc})") from None
    reward = header.get("reward_function")
    name = header.get("checkpoint_name")
    if not isinstance(name, str) or not (reward is None or isinstance(reward, str)):
        raise WireError("the import's result has a bad checkpoint name or reward function")
    extra = {k[len(EXTRA_PREFIX) :]: v for k, v in blobs.items() if k.startswith(EXTRA_PREFIX)}
    checkpoint = blobs.get(CHECKPOINT_BLOB, b"")
    if header.get("kind") == "deepracer":
        return ImportedDeepRacerModel(
            metadata=metadata,
            checkpoint_bytes=checkpoint,
            checkpoint_name=name,
            source=str(header.get("source")),
            value_head_fresh=bool(header.get("value_head_fresh")),
            hyperparameters=hyperparameters,
            reward_function=reward,
            extra_files=extra,
        )
    if hyperparameters is None or reward is None:
        raise WireError("the import's result lacks hyperparameters or a reward function")
    return ImportedModel(
        metadata=metadata,
        hyperparameters=hyperparameters,
        reward_function=reward,
        checkpoint_bytes=checkpoint,
        checkpoint_name=name,
        extra_files=extra,
    )
