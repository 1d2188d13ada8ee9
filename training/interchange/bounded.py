"""Importing an upload in a bounded child process, so that no upload can hold the worker.

:func:`import_upload` writes the upload to a private temporary folder and starts
:mod:`training.interchange.importchild` in a fresh interpreter (``subprocess``, never a fork
of the worker, its own session, a minimal environment, one thread) that limits its own
memory, CPU time and output before it reads the upload (:class:`ImportBounds`). The worker
waits at most ``wall_seconds``, then kills the child's process group. Everything the import
builds lives in the child, so its memory goes back to the system when the child ends. The
child's answer is a file in :mod:`training.interchange.importwire`'s format (no pickle),
whose size is bounded by ``result_bytes``. Every way an import can end is an
:class:`~training.interchange.archive.ArchiveError` saying what happened: the upload's own
fault as the child worded it, or :class:`ImportStopped` for a limit it hit.
"""

from __future__ import annotations

import json
import logging
import os
import resource
import signal
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from training.interchange.archive import ArchiveError, ImportedModel, ImportLimits
from training.interchange.deepracer import ImportedDeepRacerModel
from training.interchange.importwire import WireError, read_result

log = logging.getLogger(__name__)

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CHILD_MODULE = "training.interchange.importchild"
GiB = 1024**3


@dataclass(frozen=True)
class ImportBounds:
    """What one import may use.

    ``memory_bytes``: address space on top of what the child's own code takes (about 1 GB of
    mappings for Python, numpy and torch); the biggest real DeepRacer model (the 5-layer CNN
    with stereo cameras and a LIDAR, SAC) peaks at about 1.1 GB over it. ``cpu_seconds``: CPU
    time, the child's start (about 3 s) included; that model takes about 9 s.
    ``wall_seconds``: the wait, after which the child is killed (below the worker's
    300 s task limit). ``result_bytes``: the most the child may write back (that model's
    re-saved SAC checkpoint is 347 MB, plus the archive's data files).
    """

    memory_bytes: int = 3 * GiB
    cpu_seconds: int = 120
    wall_seconds: float = 180.0
    result_bytes: int = GiB


class ImportStopped(ArchiveError):
    """The import hit one of its :class:`ImportBounds` (or its process ended abnormally) and
    was stopped; the message says which."""


def _size(nbytes: int) -> str:
    if nbytes >= GiB:
        return f"{nbytes / GiB:g} GB"
    return f"{nbytes / 1024**2:g} MB"


def _child_env(folder: str) -> dict[str, str]:
    """No secrets of the worker's environment; one thread everywhere."""
    return {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "HOME": folder,
        "LANG": "C.UTF-8",
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MALLOC_ARENA_MAX": "2",
        "PYTHONDONTWRITEBYTECODE": "1",
    }


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    process.wait()


def _stderr_tail(folder: Path) -> str:
    try:
        with open(folder / "stderr", "rb") as handle:
            handle.seek(0, os.SEEK_END)
            handle.seek(max(0, handle.tell() - 2000))
            return handle.read().decode("utf-8", "replace")
    except OSError:
        return ""


def _run(folder: Path, bounds: ImportBounds, limits: ImportLimits) -> tuple[int, float]:
    """Start the child on the upload in ``folder``; its exit status (negative: a signal) and
    the CPU seconds it used. Raises :class:`ImportStopped` when it outlives
    ``wall_seconds``."""
    (folder / "limits.json").write_text(
        json.dumps({**asdict(bounds), "import_limits": asdict(limits)})
    )
    before = _children_cpu()
    with open(folder / "stderr", "wb") as stderr:
        process = subprocess.Popen(
            [sys.executable, "-s", "-E", "-m", CHILD_MODULE, str(folder)],
            cwd=PROJECT_ROOT,
            env=_child_env(str(folder)),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=stderr,
            start_new_session=True,  # its own process group, killed whole
            close_fds=True,
        )
    try:
        status = process.wait(timeout=bounds.wall_seconds)
        return status, _children_cpu() - before
    except subprocess.TimeoutExpired:
        raise ImportStopped(
            f"the import took longer than {bounds.wall_seconds:g} s and was stopped"
        ) from None
    finally:
        _stop(process)  # also when the worker's own time limit interrupts the wait


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _outcome(folder: Path, status: int, cpu: float, bounds: ImportBounds) -> ImportStopped:
    """The error for a child that ended without a result (``cpu``: the seconds it used)."""
    if status == -signal.SIGXCPU or (status == -signal.SIGKILL and cpu >= bounds.cpu_seconds):
        return ImportStopped(
            f"the import used more than {bounds.cpu_seconds} s of CPU time and was stopped"
        )
    if status == -signal.SIGXFSZ:
        return ImportStopped(
            f"the import's result is larger than {_size(bounds.result_bytes)} and was refused"
        )
    log.warning("the import child ended with status %s: %s", status, _stderr_tail(folder))
    if status == -signal.SIGKILL:  # not by its CPU limit: the system's out-of-memory killer
        return ImportStopped(
            "the import was killed by the system (signal SIGKILL), most likely for the memory "
            "it used"
        )
    if status < 0:
        name = signal.Signals(-status).name if -status in signal.valid_signals() else -status
        return ImportStopped(f"the import stopped unexpectedly (signal {name})")
    return ImportStopped(f"the import stopped unexpectedly (exit status {status})")


def import_upload(
    upload: bytes, bounds: ImportBounds | None = None, limits: ImportLimits | None = None
) -> ImportedModel | ImportedDeepRacerModel:
    """Import ``upload`` (any model archive, see
    :func:`~training.interchange.deepracer.import_model_upload`) in a bounded child process.

    Raises :class:`~training.interchange.archive.ArchiveError` naming the file at fault, or
    :class:`ImportStopped` when the import ran out of memory ("the import used more than 3 GB
    of memory and was stopped") or time, or its process could not run.
    """
    bounds = bounds or ImportBounds()
    limits = limits or ImportLimits()
    if len(upload) > limits.max_upload_bytes:
        raise ArchiveError(
            f"the upload is larger than {limits.max_upload_bytes // (1024 * 1024)} MB"
        )
    try:
        with tempfile.TemporaryDirectory(prefix="racecraft-import-") as name:
            folder = Path(name)
            (folder / "upload").write_bytes(upload)
            status, cpu = _run(folder, bounds, limits)
            result = folder / "result"
            if status != 0 or not result.exists() or result.stat().st_size == 0:
                raise _outcome(folder, status, cpu, bounds)
            if result.stat().st_size > bounds.result_bytes:
                raise ImportStopped(
                    f"the import's result is larger than {_size(bounds.result_bytes)} "
                    "and was refused"
                )
            try:
                return read_result(str(result))
            except MemoryError:
                raise ImportStopped(
                    f"the import used more than {_size(bounds.memory_bytes)} of memory and "
                    "was stopped"
                ) from None
            except WireError as exc:
                log.warning("the import child wrote a bad result: %s", exc)
                raise ImportStopped(f"the import's result could not be read ({exc})") from None
    except OSError as exc:  # no room for the temporary folder, no interpreter...
        log.warning("the import child could not run", exc_info=True)
        raise ImportStopped(f"the import could not run ({exc.strerror or exc})") from None
