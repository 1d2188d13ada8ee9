"""What a sandbox child must have in force before it loads user code, and what to tell the
operator when this machine cannot give it.

Layers overlap on purpose (seccomp and Landlock both refuse writes, the network namespace and
seccomp both cut the network, ...), so the rule is per *protection*, not per layer: each
:class:`Requirement` names the layers any one of which provides it. A child missing any
protection refuses to load the code (fail closed) unless the operator set
``RACECRAFT_ALLOW_WEAK_SANDBOX=1``; then it runs and the console warns on every page.

``RACECRAFT_SANDBOX_SIMULATE_MISSING`` (tests only, comma-separated layer names) makes the
child *report* those layers as unavailable after it has applied them all: the real layers stay
in force, so the variable can only make the sandbox refuse more, never protect less.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

ALLOW_WEAK_ENV = "RACECRAFT_ALLOW_WEAK_SANDBOX"
SIMULATE_ENV = "RACECRAFT_SANDBOX_SIMULATE_MISSING"
SIMULATED = "unavailable: simulated by " + SIMULATE_ENV

#: How an operator gets each layer, in the words of a kernel or container setting.
LAYER_HELP: dict[str, str] = {
    "namespaces": (
        "user, network, IPC and PID namespaces: run the worker as root or enable unprivileged user "
        "namespaces (sysctl kernel.unprivileged_userns_clone=1, user.max_user_namespaces > 0); "
        "in Docker the default seccomp profile refuses unshare(), so run the worker with a "
        "profile that allows it"
    ),
    "mount_namespace": (
        "a mount namespace with a root of its own (only what it may read, and its own /proc): "
        "user namespaces enabled for the worker (as for namespaces), or the worker run as root "
        "(root keeping CAP_SETFCAP, which maps uid 0 into the namespace); in Docker a seccomp "
        "profile that allows unshare(), mount() and pivot_root()"
    ),
    "rlimits": "setrlimit() must work in the worker (a container must not forbid it)",
    "no_new_privs": "prctl(PR_SET_NO_NEW_PRIVS) must work (Linux >= 3.5)",
    "landlock": (
        "Landlock: Linux >= 5.13 built with CONFIG_SECURITY_LANDLOCK=y and 'landlock' in the "
        "kernel's lsm= boot parameter"
    ),
    "signal_scope": "Landlock ABI 6 (Linux >= 6.12) to scope signals to the sandbox",
    "seccomp": (
        "seccomp: a kernel with CONFIG_SECCOMP_FILTER=y and the libseccomp2 package "
        "(apt-get install libseccomp2); a container must allow the seccomp() system call"
    ),
    "cgroup_pids": (
        "a pids cgroup: run the worker as root, or give it a delegated cgroup v2 subtree "
        "with the pids controller enabled"
    ),
    "nproc_limit": "RLIMIT_NPROC: run the worker as a user other than root",
    "cgroup_memory": (
        "a memory cgroup: run the worker as root, or give it a delegated cgroup v2 subtree "
        "with the memory controller enabled"
    ),
    "cgroup_io": (
        "an io cgroup (blkio in cgroup v1): run the worker as root, or give it a delegated "
        "cgroup v2 subtree with the io controller enabled"
    ),
    "address_space_limit": (
        "RLIMIT_AS with seccomp refusing System V and POSIX shared memory and message queues "
        "(both layers above)"
    ),
    "limits_locked": (
        "hard rlimits the worker cannot raise: no CAP_SYS_RESOURCE in the worker, or seccomp"
    ),
}


@dataclass(frozen=True)
class Requirement:
    """One protection; ``providers`` are the layers any one of which gives it."""

    name: str
    what: str
    providers: tuple[str, ...]


REQUIREMENTS: tuple[Requirement, ...] = (
    Requirement("no_writes", "no writable filesystem", ("landlock", "seccomp")),
    Requirement("no_network", "no network", ("namespaces", "seccomp")),
    Requirement(
        "no_processes", "no new processes (fork/exec)", ("seccomp", "cgroup_pids", "nproc_limit")
    ),
    Requirement("no_limit_raise", "no way to raise its resource limits", ("limits_locked",)),
    Requirement("no_signals", "no signals to other processes", ("seccomp", "signal_scope")),
    Requirement(
        "no_scheduling",
        "no changes to other processes' priority, scheduling, CPU affinity or limits",
        ("seccomp", "namespaces"),
    ),
    Requirement(
        "memory_bound",
        "a memory limit on everything it holds (shared memory included)",
        ("cgroup_memory", "address_space_limit"),
    ),
    # stat() is no Landlock right: only a root of its own hides the rest (issue 52).
    Requirement(
        "no_host_lookups",
        "no lookup of the host's files or processes (stat of /etc/shadow, /proc/<pid>) beyond "
        "what it may read",
        ("mount_namespace",),
    ),
    # What the worker's uid shares with every process of that uid on the host (issue 52).
    Requirement(
        "no_host_watch",
        "no inotify or fanotify (counted per user across the host, and seeing past Landlock) "
        "and no eviction of other processes' page cache",
        ("seccomp",),
    ),
    Requirement(
        "io_bound",
        "a bound on its disk I/O (a limit per second, or at least no reads past the page cache)",
        ("cgroup_io", "seccomp"),
    ),
    Requirement(
        "signals_bounded",
        "a bound on the signals and timers it queues (counted per user across the host)",
        ("rlimits",),
    ),
)
REQUIREMENT_NAMES = frozenset(r.name for r in REQUIREMENTS)


def layer_active(layers: Mapping[str, str], name: str) -> bool:
    return str(layers.get(name, "")).startswith("active")


def missing_requirements(layers: Mapping[str, str]) -> list[Requirement]:
    """The protections none of whose layers is active in ``layers`` (a child's report)."""
    return [r for r in REQUIREMENTS if not any(layer_active(layers, p) for p in r.providers)]


def describe_missing(missing: list[Requirement]) -> str:
    """The operator's message: what is missing on this machine and how to get it."""
    parts = []
    for req in missing:
        how = "; or ".join(LAYER_HELP[p] for p in req.providers)
        parts.append(f"{req.what} (needs {how})")
    return (
        "Reward functions cannot run safely on this machine, so this one was not run. "
        "Missing: " + " | ".join(parts) + f". To run them anyway with weaker isolation, the "
        f"operator can set {ALLOW_WEAK_ENV}=1 (not recommended)."
    )


def _flag(name: str) -> bool:
    # Anything but an explicit yes keeps the sandbox closed (settings.py rejects bad values).
    return os.environ.get(name, "").strip().lower() in ("1", "true", "yes", "on")


def weak_sandbox_allowed() -> bool:
    """True when the operator accepted weaker isolation (``RACECRAFT_ALLOW_WEAK_SANDBOX``)."""
    return _flag(ALLOW_WEAK_ENV)


def simulated_missing() -> tuple[str, ...]:
    """Layer names the child must report as unavailable (tests only; see module docstring)."""
    raw = os.environ.get(SIMULATE_ENV, "")
    return tuple(sorted({n.strip() for n in raw.split(",") if n.strip() in LAYER_HELP}))


def apply_simulation(layers: dict[str, str], names: tuple[str, ...]) -> None:
    """Mark ``names`` as unavailable in the report (never touches the layers themselves)."""
    for name in names:
        if name in LAYER_HELP:
            layers[name] = SIMULATED
