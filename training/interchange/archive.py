"""Importing a virtual model a user uploads (``.tar.gz``, ``.tar`` or ``.zip``), safely.

The upload is read into memory within :class:`ImportLimits` (upload size, total uncompressed
size, member count), never extracted to disk. Members must be regular files or folders with
relative names: absolute paths, ``..`` segments, backslashes, links, devices, encrypted zip
members and duplicate names are refused. One common top folder (``my-model/...``) is allowed.

Required (at ``model/`` or ``ip/`` or the top level): ``model_metadata.json`` (checked by
:mod:`training.rl.metadata`; the network it names is ``racecraft_neural_network`` where the
download wrote DeepRacer's name for DeepRacer's tools), ``hyperparameters.json`` (by
:func:`parse_hyperparameters`), ``reward_function.py`` (UTF-8, at most 140,000 characters) and
a Racecraft checkpoint, an SB3 ``model/<name>.zip`` (the one ``deepracer_checkpoints.json``
names best, else last, through ``racecraft_checkpoint`` where the name is DeepRacer's
checkpoint, else ``best.zip``/``last.zip``/the only one). The checkpoint must load for the
metadata's algorithm, network, camera and action space
(:func:`training.rl.checkpoints.load_checkpoint`; nothing in it is unpickled), its weights
must all be finite numbers (a NaN or an infinity is refused naming the weight), and it is
returned re-saved by Racecraft. DeepRacer's TensorFlow checkpoints are not read here (the DeepRacer
import, :mod:`training.interchange.deepracer`, reads them). Every failure is an
:class:`ArchiveError` naming the file.
"""

from __future__ import annotations

import dataclasses
import gzip
import io
import json
import stat
import tarfile
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import BinaryIO

from training.interchange.carmodel import RACECRAFT_NETWORK_KEY
from training.interchange.export import CheckpointError, checkpoint_bytes, load_checkpoint
from training.interchange.integrity import first_non_finite
from training.interchange.policybuild import model_weights
from training.rl.hyperparams import HyperparameterError, Hyperparameters, parse_hyperparameters
from training.rl.metadata import MetadataError, ModelMetadata, parse_metadata
from training.rl.policies import NETWORKS
from training.sandbox.static import source_too_long

TF_SUFFIXES = (".pb", ".ckpt", ".index", ".meta", ".coach_checkpoint")
EXTRA_SUFFIXES = (".json", ".yaml", ".yml", ".csv", ".txt", ".log", ".md")
"""Other files kept from an upload (metrics, training_params.yaml...); never code or weights."""


class ArchiveError(ValueError):
    """An upload that cannot be imported; the message names the file at fault."""


@dataclass(frozen=True)
class ImportLimits:
    """Bytes of the upload, bytes once uncompressed (all members), number of members."""

    max_upload_bytes: int = 200 * 1024 * 1024
    max_uncompressed_bytes: int = 500 * 1024 * 1024
    max_members: int = 1000


@dataclass(frozen=True)
class ImportedModel:
    """A validated upload. ``checkpoint_bytes`` is the checkpoint re-saved by Racecraft (an SB3
    zip to store as ``model/<checkpoint_name>.zip``); ``extra_files`` are the other data files
    (``metrics/TrainingMetrics.json``...) by their name inside the model folder."""

    metadata: ModelMetadata
    hyperparameters: Hyperparameters
    reward_function: str
    checkpoint_bytes: bytes
    checkpoint_name: str
    extra_files: dict[str, bytes] = field(default_factory=dict)


def _read_upload(upload: bytes | BinaryIO, limits: ImportLimits) -> bytes:
    if isinstance(upload, bytes | bytearray | memoryview):
        data = bytes(upload)
    else:
        data = upload.read(limits.max_upload_bytes + 1)
    if len(data) > limits.max_upload_bytes:
        raise ArchiveError(
            f"the upload is larger than {limits.max_upload_bytes // (1024 * 1024)} MB"
        )
    if not data:
        raise ArchiveError("the upload is empty")
    return data


def _clean_name(name: str) -> str:
    """A member name checked and normalised (``./a/b/`` → ``a/b``)."""
    if "\\" in name or "\x00" in name:
        raise ArchiveError(f"{name!r}: backslashes and NUL characters are not allowed in names")
    if name.startswith("/") or (len(name) > 1 and name[1] == ":"):
        raise ArchiveError(f"{name}: absolute paths are not allowed")
    parts = [p for p in name.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise ArchiveError(f"{name}: '..' is not allowed in names")
    return "/".join(parts)


class _Budget:
    """Counts members and uncompressed bytes against the limits."""

    def __init__(self, limits: ImportLimits) -> None:
        self.limits, self.members, self.bytes = limits, 0, 0

    def member(self, name: str) -> None:
        self.members += 1
        if self.members > self.limits.max_members:
            raise ArchiveError(f"the archive has more than {self.limits.max_members} files")

    def take(self, name: str, size: int) -> None:
        self.bytes += size
        if self.bytes > self.limits.max_uncompressed_bytes:
            raise ArchiveError(
                f"{name}: the archive holds more than "
                f"{self.limits.max_uncompressed_bytes // (1024 * 1024)} MB once uncompressed"
            )


class _CappedReader(io.RawIOBase):
    """A stream that fails once more than ``cap`` bytes were read from it (gzip-bomb guard)."""

    def __init__(self, inner: BinaryIO, cap: int) -> None:
        self.inner, self.cap, self.read_so_far = inner, cap, 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        data = self.inner.read(len(buffer))
        self.read_so_far += len(data)
        if self.read_so_far > self.cap:
            raise ArchiveError("the archive holds too much data once uncompressed")
        buffer[: len(data)] = data
        return len(data)


def _read_tar(data: bytes, budget: _Budget) -> dict[str, bytes]:
    raw: BinaryIO = io.BytesIO(data)
    if data[:2] == b"\x1f\x8b":
        raw = gzip.GzipFile(fileobj=raw, mode="rb")
    # Headers and padding count too: allow 2 KiB per member on top of the data.
    cap = budget.limits.max_uncompressed_bytes + 2048 * (budget.limits.max_members + 2)
    files: dict[str, bytes] = {}
    with tarfile.open(fileobj=_CappedReader(raw, cap), mode="r|") as tar:
        for member in tar:
            budget.member(member.name)
            name = _clean_name(member.name)
            if member.issym() or member.islnk():
                raise ArchiveError(f"{member.name}: links are not allowed")
            if member.isdir():
                continue
            if not name:
                raise ArchiveError(f"{member.name!r}: a file needs a name")
            if not member.isreg() or member.issparse():
                raise ArchiveError(f"{member.name}: only regular files are allowed (no devices)")
            if name in files:
                raise ArchiveError(f"{name}: the archive holds this name twice")
            budget.take(name, member.size)
            handle = tar.extractfile(member)
            files[name] = handle.read(member.size + 1) if handle else b""
    return files


def _read_zip(data: bytes, budget: _Budget) -> dict[str, bytes]:
    files: dict[str, bytes] = {}
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        infos = archive.infolist()
        for info in infos:  # everything is checked before anything is decompressed
            budget.member(info.filename)
            name = _clean_name(info.filename)
            mode = info.external_attr >> 16
            if stat.S_ISLNK(mode):
                raise ArchiveError(f"{info.filename}: links are not allowed")
            if info.is_dir():
                continue
            if not name:
                raise ArchiveError(f"{info.filename!r}: a file needs a name")
            if stat.S_IFMT(mode) not in (0, stat.S_IFREG):
                raise ArchiveError(f"{info.filename}: only regular files are allowed")
            if info.flag_bits & 0x1:
                raise ArchiveError(f"{info.filename}: encrypted files are not supported")
            if name in files:
                raise ArchiveError(f"{name}: the archive holds this name twice")
            budget.take(name, info.file_size)
            files[name] = b""
        for info in infos:
            if not info.is_dir():
                with archive.open(info) as handle:
                    files[_clean_name(info.filename)] = handle.read(info.file_size + 1)
    return files


def read_archive(upload: bytes | BinaryIO, limits: ImportLimits | None = None) -> dict[str, bytes]:
    """Every regular file of a tar(.gz) or zip upload, name → bytes, within ``limits``.

    Raises :class:`ArchiveError` for an unsafe, oversized or unreadable archive.
    """
    limits = limits or ImportLimits()
    data = _read_upload(upload, limits)
    budget = _Budget(limits)
    try:
        if data[:4] in (b"PK\x03\x04", b"PK\x05\x06"):
            files = _read_zip(data, budget)
        elif data[:2] == b"\x1f\x8b" or data[257:262] == b"ustar":
            files = _read_tar(data, budget)
        else:
            raise ArchiveError("the upload is not a .tar.gz, .tar or .zip file")
    except ArchiveError:
        raise
    except (
        tarfile.TarError,
        zipfile.BadZipFile,
        zipfile.LargeZipFile,
        EOFError,
        OSError,
        zlib.error,
    ) as exc:
        raise ArchiveError(f"the archive is damaged and cannot be read ({exc})") from None
    except (ValueError, NotImplementedError, RuntimeError) as exc:
        raise ArchiveError(f"the archive cannot be read ({exc})") from None
    return _strip_top_folder(files)


def _strip_top_folder(files: dict[str, bytes]) -> dict[str, bytes]:
    """``my-model/model/...`` → ``model/...`` when every file sits in one top folder."""
    tops = {name.split("/", 1)[0] for name in files}
    if len(tops) == 1 and all("/" in name for name in files):
        top = tops.pop()
        if top not in ("model", "ip"):
            return {name.split("/", 1)[1]: data for name, data in files.items()}
    return files


def _find(files: Mapping[str, bytes], *names: str) -> str:
    for name in names:
        if name in files:
            return name
    raise ArchiveError(f"{names[0]} is missing (looked for {', '.join(names)})")


def read_json(files: Mapping[str, bytes], name: str) -> object:
    """The JSON file ``name`` of ``files``; raises :class:`ArchiveError` naming it."""
    try:
        text = files[name].decode("utf-8-sig")
        return json.loads(text, parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise ArchiveError(f"{name}: not valid JSON ({exc})") from None
    except RecursionError:
        raise ArchiveError(f"{name}: nested too deeply to read") from None


def read_metadata(files: Mapping[str, bytes], name: str) -> ModelMetadata:
    """The ``model_metadata.json`` ``name`` of ``files``; raises :class:`ArchiveError` naming
    it (for JSON nested too deeply to read too)."""
    try:
        return parse_metadata(files[name])
    except MetadataError as exc:
        raise ArchiveError(f"{name}: {exc}") from None
    except RecursionError:
        raise ArchiveError(f"{name}: nested too deeply to read") from None


def _racecraft_network(metadata: ModelMetadata, name: str) -> ModelMetadata:
    """The metadata with Racecraft's own network where the file names DeepRacer's and keeps
    Racecraft's aside (:data:`~training.interchange.carmodel.RACECRAFT_NETWORK_KEY`), as the
    download writes it for DeepRacer's tools."""
    own = metadata.extra.get(RACECRAFT_NETWORK_KEY)
    if own is None:
        return metadata
    if own not in NETWORKS:
        raise ArchiveError(f"{name}: {RACECRAFT_NETWORK_KEY} {own!r} is not a Racecraft network")
    extra = {k: v for k, v in metadata.extra.items() if k != RACECRAFT_NETWORK_KEY}
    return dataclasses.replace(metadata, neural_network=own, extra=extra)


def _refuse_constant(name: str) -> object:
    raise ValueError(f"{name} is not allowed")


def reward_source(files: Mapping[str, bytes], name: str) -> str:
    """The reward function ``name`` as text; raises :class:`ArchiveError` when it is not
    UTF-8, too long, empty or holds NUL characters."""
    try:
        source = files[name].decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ArchiveError(f"{name}: not UTF-8 text (byte {exc.start})") from None
    if (too_long := source_too_long(source)) is not None:
        raise ArchiveError(f"{name}: {too_long.message}")
    if "\x00" in source:
        raise ArchiveError(f"{name}: contains NUL characters")
    if not source.strip():
        raise ArchiveError(f"{name}: is empty")
    return source


def _checkpoint_name(files: Mapping[str, bytes]) -> str:
    """The archive name of the checkpoint to import (``model/<name>.zip``)."""
    folder = "model/" if any(n.startswith("model/") for n in files) else ""
    zips = sorted(
        n
        for n in files
        if n.startswith(folder) and n.endswith(".zip") and "/" not in n[len(folder) :]
    )
    index_name = next((n for n in (f"{folder}deepracer_checkpoints.json",) if n in files), None)
    if index_name:
        index = read_json(files, index_name)
        for role in ("best_checkpoint", "last_checkpoint"):
            entry = index.get(role) if isinstance(index, dict) else None
            for key in ("racecraft_checkpoint", "name"):  # the zip a DeepRacer checkpoint is of
                named = entry.get(key) if isinstance(entry, dict) else None
                if isinstance(named, str) and named:
                    candidate = f"{folder}{named.removesuffix('.zip')}.zip"
                    if candidate in files:
                        return candidate
    for preferred in ("best.zip", "last.zip"):
        if f"{folder}{preferred}" in files:
            return f"{folder}{preferred}"
    if len(zips) == 1:
        return zips[0]
    if zips:
        raise ArchiveError(
            f"{folder}deepracer_checkpoints.json is needed to choose among {', '.join(zips)}"
        )
    tf = sorted(n for n in files if n.endswith(TF_SUFFIXES) or ".ckpt." in n)
    if tf:
        raise ArchiveError(
            f"{tf[0]}: this is a DeepRacer TensorFlow model, which Racecraft cannot load; "
            "only models exported from Racecraft (with an SB3 model/<name>.zip checkpoint) "
            "can be imported with their weights"
        )
    raise ArchiveError(f"{folder or 'model/'}<checkpoint>.zip is missing: no checkpoint to import")


def import_virtual_model(
    upload: bytes | BinaryIO, limits: ImportLimits | None = None
) -> ImportedModel:
    """Validate an uploaded virtual model and return its parts (see the module docstring).

    Raises :class:`ArchiveError` naming the file at fault.
    """
    return virtual_model(read_archive(upload, limits))


def virtual_model(files: Mapping[str, bytes]) -> ImportedModel:
    """:func:`import_virtual_model` of an archive already read by :func:`read_archive`."""
    meta_name = _find(files, "model/model_metadata.json", "model_metadata.json")
    metadata = _racecraft_network(read_metadata(files, meta_name), meta_name)
    hp_name = _find(files, "ip/hyperparameters.json", "hyperparameters.json")
    try:
        hyperparameters = parse_hyperparameters(
            read_json(files, hp_name), metadata.training_algorithm
        )
    except HyperparameterError as exc:
        raise ArchiveError(f"{hp_name}: {exc}") from None
    reward_name = _find(files, "reward_function.py")
    reward = reward_source(files, reward_name)
    ckpt_name = _checkpoint_name(files)
    try:
        model = load_checkpoint(files[ckpt_name], metadata)
    except CheckpointError as exc:
        raise ArchiveError(f"{ckpt_name}: {exc}") from None
    bad = first_non_finite(model_weights(model))
    if bad is not None:
        raise ArchiveError(
            f"{ckpt_name}: the weight {bad[0]!r} holds {bad[1]}; a model's weights must be "
            "finite numbers"
        )
    used = {meta_name, hp_name, reward_name, ckpt_name}
    extra = {
        name: data
        for name, data in sorted(files.items())
        if name not in used
        and name.endswith(EXTRA_SUFFIXES)
        and not name.startswith("model/")
        and name not in ("deepracer_checkpoints.json", "model_metadata.json")  # DRoA's copy
    }
    return ImportedModel(
        metadata=metadata,
        hyperparameters=hyperparameters,
        reward_function=reward,
        checkpoint_bytes=checkpoint_bytes(model),
        checkpoint_name=ckpt_name.rsplit("/", 1)[-1].removesuffix(".zip"),
        extra_files=extra,
    )
