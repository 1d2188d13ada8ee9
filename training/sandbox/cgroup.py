"""A pids cgroup per sandbox child: the fallback that refuses new processes when seccomp is
missing and the caller is root (RLIMIT_NPROC never applies to uid 0).

The parent creates ``racecraft-sandbox-<pid>`` beside its own pids cgroup (v1, or v2 with
the pids controller delegated), sets ``pids.max`` and moves the child in before the child
receives its job, so before any user code runs. Needs write access to the cgroup tree
(root, or a delegated subtree); otherwise the layer reports why it is unavailable.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

V1_ROOT = Path("/sys/fs/cgroup/pids")
V2_ROOT = Path("/sys/fs/cgroup")


def _own_cgroup(controller: str | None) -> str | None:
    with open("/proc/self/cgroup") as f:
        for line in f:
            _, controllers, path = line.rstrip("\n").split(":", 2)
            if controller is None and controllers == "":
                return path
            if controller is not None and controller in controllers.split(","):
                return path
    return None


def _base() -> Path | None:
    if (V1_ROOT / "cgroup.procs").exists():
        own = _own_cgroup("pids")
        return V1_ROOT / own.lstrip("/") if own is not None else None
    if (V2_ROOT / "cgroup.controllers").exists():
        own = _own_cgroup(None)
        if own is None:
            return None
        parent = V2_ROOT / own.lstrip("/")
        if "pids" in (parent / "cgroup.subtree_control").read_text().split():
            return parent
    return None


PREFIX = "racecraft-sandbox-"


def _sweep(base: Path) -> None:
    """Remove cgroups left by parents that died before cleaning up (their child is gone)."""
    for entry in base.glob(f"{PREFIX}*"):
        pid = entry.name.removeprefix(PREFIX)
        if pid.isdigit() and not _alive(int(pid)):
            with contextlib.suppress(OSError):
                os.rmdir(entry)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


class PidsCgroup:
    """``confine(pid)`` returns None when the child is confined, else the reason not;
    ``remove()`` deletes the cgroup once the child is gone."""

    def __init__(self, max_pids: int) -> None:
        self.max_pids = max_pids
        self.path: Path | None = None

    def confine(self, pid: int) -> str | None:
        try:
            base = _base()
            if base is None:
                return "no pids cgroup controller available"
            _sweep(base)
            path = base / f"{PREFIX}{pid}"
            path.mkdir()
            self.path = path
            (path / "pids.max").write_text(str(self.max_pids))
            (path / "cgroup.procs").write_text(str(pid))
        except OSError as exc:
            self.remove()
            return f"cannot use the pids cgroup: {exc.strerror or exc}"
        return None

    def remove(self) -> None:
        if self.path is not None:
            with contextlib.suppress(OSError):
                os.rmdir(self.path)
            self.path = None
