"""A cgroup per sandbox child, one per controller: ``pids`` (the fallback that refuses new
processes when seccomp is missing and the caller is root: RLIMIT_NPROC never applies to uid
0), ``memory`` (a limit the kernel enforces on everything the child holds: anonymous
memory, System V and POSIX shared memory, page cache, kernel memory; the address-space rlimit
misses what is not mapped) and ``io`` (``blkio`` in v1: bytes and requests per second on each
disk, so a child reading files cannot take the disk from the host's other processes).

The parent creates ``racecraft-sandbox-<pid>`` beside its own cgroup of that controller (v1,
or v2 with the controller delegated to the parent's cgroup), sets the limit and moves the
child in before the child receives its job, so before any user code runs. Needs write access
to the cgroup tree (root, or a delegated subtree); otherwise the layer reports why it is
unavailable and the sandbox relies on the other layers that give the same protection
(:mod:`training.sandbox.requirements`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import time
from pathlib import Path

ROOT = Path("/sys/fs/cgroup")
PREFIX = "racecraft-sandbox-"
REMOVE_TRIES = 100


def _own_cgroup(controller: str | None) -> str | None:
    with open("/proc/self/cgroup") as f:
        for line in f:
            _, controllers, path = line.rstrip("\n").split(":", 2)
            if controller is None and controllers == "":
                return path
            if controller is not None and controller in controllers.split(","):
                return path
    return None


def _base(controller: str, v1_name: str) -> tuple[Path, int] | None:
    """The folder to create the child's cgroup in, and the cgroup version (1 or 2)."""
    v1 = ROOT / v1_name
    if (v1 / "cgroup.procs").exists():
        own = _own_cgroup(v1_name)
        return (v1 / own.lstrip("/"), 1) if own is not None else None
    if (ROOT / "cgroup.controllers").exists():
        own = _own_cgroup(None)
        if own is None:
            return None
        parent = ROOT / own.lstrip("/")
        if controller in (parent / "cgroup.subtree_control").read_text().split():
            return parent, 2
    return None


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


class ChildCgroup:
    """``confine(pid)`` returns None when the child is confined, else the reason not;
    ``remove()`` deletes the cgroup once the child is gone. Subclasses name the controller
    and write its limits (:meth:`_limit`)."""

    controller = ""
    #: The controller's name in cgroup v1 where it differs (``blkio`` for ``io``).
    v1_controller = ""

    def __init__(self) -> None:
        self.path: Path | None = None
        self.version = 0

    def _limit(self, path: Path) -> None:
        raise NotImplementedError

    def confine(self, pid: int) -> str | None:
        try:
            found = _base(self.controller, self.v1_controller or self.controller)
            if found is None:
                return f"no {self.controller} cgroup controller available"
            base, self.version = found
            _sweep(base)
            path = base / f"{PREFIX}{pid}"
            path.mkdir()
            self.path = path
            self._limit(path)
            (path / "cgroup.procs").write_text(str(pid))
        except OSError as exc:
            self.remove()
            return f"cannot use the {self.controller} cgroup: {exc.strerror or exc}"
        return None

    def remove(self) -> None:
        """Delete the cgroup. A child killed with its waiter may take a moment to leave it
        (EBUSY): try for up to a second, then leave it to the next sandbox's sweep."""
        if self.path is not None:
            for _ in range(REMOVE_TRIES):
                try:
                    os.rmdir(self.path)
                    break
                except OSError as exc:
                    if exc.errno != errno.EBUSY:
                        break
                    time.sleep(0.01)
            self.path = None


class PidsCgroup(ChildCgroup):
    """At most ``max_pids`` processes and threads in the child's cgroup."""

    controller = "pids"

    def __init__(self, max_pids: int) -> None:
        super().__init__()
        self.max_pids = max_pids

    def _limit(self, path: Path) -> None:
        (path / "pids.max").write_text(str(self.max_pids))


class MemoryCgroup(ChildCgroup):
    """A hard memory limit on the child's cgroup, without swap: ``limit_bytes`` at first (the
    child's imports, our own code), then :meth:`tighten` to what it holds plus its allowance
    once it is locked down and before it loads user code. Past the limit the kernel reclaims,
    then kills the child (:meth:`oom_killed` says whether it did)."""

    controller = "memory"

    def __init__(self, limit_bytes: int) -> None:
        super().__init__()
        self.limit_bytes = limit_bytes

    def _files(self) -> tuple[str, str, str]:
        """(limit, swap limit, usage) file names of this cgroup version."""
        if self.version == 1:
            return "memory.limit_in_bytes", "memory.memsw.limit_in_bytes", "memory.usage_in_bytes"
        return "memory.max", "memory.swap.max", "memory.current"

    def _limit(self, path: Path) -> None:
        self._set(path, self.limit_bytes)

    def _set(self, path: Path, limit: int) -> None:
        limit_file, swap_file, _ = self._files()
        if self.version == 1:
            # memsw (memory + swap) may not go below memory, nor memory above memsw: order.
            current = int((path / limit_file).read_text())
            pairs = [(limit_file, limit), (swap_file, limit)]
            if limit > current:
                pairs.reverse()
            for name, value in pairs:
                if (path / name).exists():
                    (path / name).write_text(str(value))
        else:
            (path / limit_file).write_text(str(limit))
            if (path / swap_file).exists():
                (path / swap_file).write_text("0")
        self.limit_bytes = limit

    def usage(self) -> int | None:
        """Bytes the child's cgroup holds now, or None when it is not confined."""
        if self.path is None:
            return None
        try:
            return int((self.path / self._files()[2]).read_text())
        except (OSError, ValueError):
            return None

    def tighten(self, allowance: int) -> str | None:
        """Limit the cgroup to its current usage plus ``allowance`` bytes (never above the
        first limit); None when done, else why not."""
        used = self.usage()
        if self.path is None or used is None:
            return "not confined"
        try:
            self._set(self.path, min(self.limit_bytes, used + allowance))
        except OSError as exc:
            return f"cannot set the memory limit: {exc.strerror or exc}"
        return None

    def oom_killed(self) -> bool:
        """Whether the kernel killed a process of this cgroup for memory."""
        if self.path is None:
            return False
        name = "memory.oom_control" if self.version == 1 else "memory.events"
        try:
            for line in (self.path / name).read_text().splitlines():
                key, _, value = line.partition(" ")
                if key == "oom_kill" and value.strip().isdigit() and int(value) > 0:
                    return True
        except OSError:
            return False
        return False


def block_devices(sys_block: Path = Path("/sys/block")) -> list[tuple[str, bool]]:
    """Each disk of the machine as ``("major:minor", has_media)``; partitions go through their
    disk, so limiting the disks limits them. ``has_media`` is False for an empty loop or
    zram device (size 0)."""
    found = []
    for entry in sorted(sys_block.iterdir()):
        try:
            dev = (entry / "dev").read_text().strip()
            size = int((entry / "size").read_text())
        except (OSError, ValueError):
            continue
        found.append((dev, size > 0))
    return found


class IoCgroup(ChildCgroup):
    """At most ``bytes_per_second`` and ``ops_per_second`` of reads, and as much of writes, on
    every disk, for everything in the child's cgroup (v2 ``io.max``, v1 ``blkio.throttle.*``).

    The child's reads go through the page cache (seccomp refuses O_DIRECT): a read served
    from the cache costs the disk nothing and is not paced; one that misses waits its turn.
    A disk that refuses a limit while it has no media (an empty loop device) is skipped; any
    other refusal leaves the layer unavailable."""

    controller = "io"
    v1_controller = "blkio"

    def __init__(
        self, bytes_per_second: int, ops_per_second: int, sys_block: Path = Path("/sys/block")
    ) -> None:
        super().__init__()
        self.bytes_per_second = bytes_per_second
        self.ops_per_second = ops_per_second
        self.sys_block = sys_block

    def _limit(self, path: Path) -> None:
        devices = block_devices(self.sys_block)
        if not any(media for _, media in devices):
            raise OSError(errno.ENODEV, f"no disk found in {self.sys_block}")
        bps, iops = self.bytes_per_second, self.ops_per_second
        for dev, media in devices:
            try:
                if self.version == 1:
                    for name, value in (
                        ("read_bps_device", bps),
                        ("write_bps_device", bps),
                        ("read_iops_device", iops),
                        ("write_iops_device", iops),
                    ):
                        (path / f"blkio.throttle.{name}").write_text(f"{dev} {value}")
                else:
                    line = f"{dev} rbps={bps} wbps={bps} riops={iops} wiops={iops}"
                    (path / "io.max").write_text(line)
            except OSError:
                if media:
                    raise

    def limits(self) -> dict[str, str]:
        """What the kernel holds for this cgroup now, by device: the v2 ``io.max`` line, or
        the v1 throttle values joined; empty when it is not confined. For tests and checks."""
        if self.path is None:
            return {}
        found: dict[str, list[str]] = {}
        names = (
            ["io.max"]
            if self.version == 2
            else [f"blkio.throttle.{k}" for k in ("read_bps_device", "read_iops_device")]
        )
        for name in names:
            for line in (self.path / name).read_text().splitlines():
                dev, _, rest = line.partition(" ")
                found.setdefault(dev, []).append(rest)
        return {dev: " ".join(parts) for dev, parts in found.items()}
