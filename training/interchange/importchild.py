"""The child of a bounded import: ``python -m training.interchange.importchild FOLDER``.

Started by :func:`training.interchange.bounded.import_upload` as a fresh interpreter (never a
fork of the worker). It limits itself before it reads the upload: no core files, CPU seconds
(``RLIMIT_CPU``: SIGXCPU, then SIGKILL 5 s later), the bytes it may write (``RLIMIT_FSIZE``:
the result's bound), and once its own code is loaded, its address space (``RLIMIT_AS``: what
the code occupies plus the memory budget, so the budget is what the upload may cost). Then it
reads ``FOLDER/upload``, imports it (:func:`training.interchange.deepracer.import_model_upload`)
and writes ``FOLDER/result`` (:mod:`training.interchange.importwire`): the model, or the
refusal with its reason. It exits 0 whenever it could write a result.
"""

from __future__ import annotations

import json
import resource
import sys
from pathlib import Path

CPU_GRACE_S = 5


def _limit(which: int, soft: int, hard: int | None = None) -> None:
    hard = soft if hard is None else hard
    current_soft, current_hard = resource.getrlimit(which)
    if current_hard != resource.RLIM_INFINITY:
        hard = min(hard, current_hard)
    resource.setrlimit(which, (min(soft, hard), hard))


def _address_space() -> int:
    """Bytes of address space this process holds now (``VmSize``)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 2 * 1024**3  # no /proc: assume what the interpreter and torch take


def limit_self(folder: Path) -> dict:
    """Read ``FOLDER/limits.json`` and apply the limits that come before any import: no core
    files, CPU seconds, bytes written. Returns the limits."""
    limits = json.loads((folder / "limits.json").read_text())
    _limit(resource.RLIMIT_CORE, 0)
    _limit(resource.RLIMIT_CPU, limits["cpu_seconds"], limits["cpu_seconds"] + CPU_GRACE_S)
    _limit(resource.RLIMIT_FSIZE, limits["result_bytes"])
    return limits


def main(folder: Path) -> int:
    limits = limit_self(folder)

    # Imported after the CPU and output limits, before the memory one: the address-space
    # limit is what the code occupies plus the budget, so the code must be loaded first.
    import torch

    from training.interchange.archive import ArchiveError, ImportLimits
    from training.interchange.deepracer import import_model_upload
    from training.interchange.importwire import write_error, write_result

    torch.set_num_threads(1)  # no thread pool to start under the address-space limit
    budget = limits["memory_bytes"]
    _limit(resource.RLIMIT_AS, _address_space() + budget)
    with open(folder / "result", "wb") as out:
        try:
            upload = (folder / "upload").read_bytes()
            imported = import_model_upload(upload, ImportLimits(**limits["import_limits"]))
            write_result(out, imported)
            return 0
        except ArchiveError as exc:
            message, reason = str(exc), "archive"
        except MemoryError:
            message, reason = "out of memory", "memory"
        except RecursionError:
            message, reason = "the archive holds data nested too deeply to read", "archive"
        except Exception as exc:  # the reason, in words, rather than a failed task
            text = str(exc)
            if "can't allocate memory" in text:  # torch's allocator under RLIMIT_AS
                message, reason = "out of memory", "memory"
            else:
                message = f"the archive cannot be imported ({type(exc).__name__}: {text[:300]})"
                reason = "archive"
        out.seek(0)
        out.truncate()
        write_error(out, message, reason)
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
