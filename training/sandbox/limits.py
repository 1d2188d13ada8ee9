"""Resource limits of one sandbox process."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any


@dataclass(frozen=True)
class SandboxLimits:
    """Limits applied to a sandbox process (all enforced by the OS or by the parent).

    per_call_seconds: wall-clock limit for one call of ``reward_function`` (and for running
        the module's top level); the parent's watchdog kills the child when it is passed.
    cpu_seconds: total CPU time of the child (RLIMIT_CPU, SIGKILL one second later).
    memory_bytes: address space the child may add after its imports (RLIMIT_AS is set to
        the size at lock-down plus this).
    open_files: RLIMIT_NOFILE.
    max_output_chars: characters of ``print`` output kept per process; the rest is dropped.
    max_message_bytes: the parent refuses (and kills the child for) larger messages (their
        JSON part is bounded further: :mod:`training.sandbox.protocol`).
    start_seconds: time allowed from spawn to ready (imports, lock-down, loading the module).
    allow_threads: let the child create threads (e.g. a rollout using torch intra-op threads);
        processes are refused either way.
    read_paths: extra directories the child may read after lock-down (Landlock).
    disk_bytes_per_second, disk_ops_per_second: what the child may read (and write) of each
        block device of the machine, in bytes and in requests per second, from its start (its
        imports included); its io (cgroup v2) or blkio (v1) cgroup holds it there
        (:class:`~training.sandbox.cgroup.IoCgroup`), so one job cannot take the disk from the
        host's other processes. Reads served from the page cache do not count.
    """

    per_call_seconds: float = 1.0
    cpu_seconds: int = 3600
    memory_bytes: int = 1 << 30
    open_files: int = 64
    max_output_chars: int = 64_000
    max_message_bytes: int = 32 << 20
    start_seconds: float = 30.0
    allow_threads: bool = False
    read_paths: tuple[str, ...] = field(default_factory=tuple)
    disk_bytes_per_second: int = 64 << 20
    disk_ops_per_second: int = 1000

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["read_paths"] = list(self.read_paths)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SandboxLimits:
        known = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in data.items() if k in known}
        if "read_paths" in kwargs:
            kwargs["read_paths"] = tuple(kwargs["read_paths"])
        return cls(**kwargs)


#: RLIMIT_SIGPENDING of every child: real-time signals it may have queued plus POSIX timers it
#: may hold (each timer is charged one), counted against the worker's uid (issue 52: 20,000 of
#: them made a bystander's ``timer_create`` fail). CPython, numpy and torch queue none.
MAX_PENDING_SIGNALS = 64

#: Validation: DeepRacer gives every runtime test 5 s.
VALIDATION_LIMITS = SandboxLimits(per_call_seconds=5.0, cpu_seconds=120)
