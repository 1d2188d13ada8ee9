"""The OS layers a sandbox child applies to itself, in order, each independent of the others.

Order matters: namespaces need a single-threaded process (first, before any import); the
rlimit on memory is sized after the imports; no_new_privs must precede Landlock and seccomp;
seccomp comes last because it refuses the syscalls the earlier layers use (unshare, open for
write). Every function returns None when its layer is active, else the reason it is not; the
child reports the lot to the parent (:class:`LayerReport`).
"""

from __future__ import annotations

import ctypes
import os
import resource
import signal
import sys
from collections.abc import Callable
from pathlib import Path

from training.sandbox import landlock, rootfs, seccomp

ACTIVE = "active"
CLONE_NEWIPC = 0x08000000
CLONE_NEWNS = 0x00020000
CLONE_NEWPID = 0x20000000
CLONE_NEWUSER = 0x10000000
CLONE_NEWNET = 0x40000000
PR_SET_NO_NEW_PRIVS = 38
PR_SET_DUMPABLE = 4

#: The only environment a sandbox child ever has.
CHILD_ENV: dict[str, str] = {
    "PATH": "/usr/bin:/bin",
    "LANG": "C.UTF-8",
    "PYTHONHASHSEED": "0",
    "PYTHONDONTWRITEBYTECODE": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}

LayerReport = dict[str, str]


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(None, use_errno=True)


def clean_environment() -> str | None:
    """Drop every environment variable except the fixed, secret-free :data:`CHILD_ENV`."""
    os.environ.clear()
    os.environ.update(CHILD_ENV)
    return None


def close_inherited_fds(keep: set[int]) -> str | None:
    """Point 0/1/2 at /dev/null and close every other descriptor not in ``keep``."""
    null = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1, 2):
        os.dup2(null, fd)
    if null > 2:
        os.close(null)
    for name in os.listdir("/proc/self/fd") if os.path.isdir("/proc/self/fd") else []:
        fd = int(name)
        if fd > 2 and fd not in keep:
            try:
                os.close(fd)
            except OSError:
                pass
    return None


#: Why this process has no mount namespace of its own, private, to build its root in (None
#: once :func:`unshare_namespaces` made one); and whether it is PID 1 of a PID namespace of
#: its own (then it gets a fresh /proc).
_no_mount_namespace: str | None = "not made (test only)"
_own_pid_namespace = False


def unshare_namespaces(*, others: bool = True, mount: bool = True) -> str | None:
    """New user (where possible), network (no interfaces), IPC (System V objects of its own,
    gone with it), PID namespaces (``others``) and mount namespace (``mount``: its root is
    built at lock-down, :func:`isolate_filesystem`); with a PID namespace, then fork: the rest
    of the child runs as PID 1 of the new PID namespace, where no host process can be named
    (setpriority, sched_setaffinity, kill and /proc lookups by pid see only the sandbox). The
    process that called this waits for it and exits with its status (:func:`_wait_and_exit`);
    it runs no user code.

    Unprivileged users need the user namespace to get the others; root gets them even where
    user namespaces are disabled. Must run single-threaded, with only the descriptors the
    child needs open. Returns None or why the namespaces were not made; why the mount
    namespace is missing is kept apart (:func:`isolate_filesystem` reports it).
    """
    global _no_mount_namespace, _own_pid_namespace
    libc = _libc()
    flags = (CLONE_NEWNET | CLONE_NEWIPC | CLONE_NEWPID if others else 0) | (
        CLONE_NEWNS if mount else 0
    )
    uid, gid = os.geteuid(), os.getegid()
    own_user = libc.unshare(CLONE_NEWUSER | flags) == 0
    if not own_user:
        first = os.strerror(ctypes.get_errno())
        if libc.unshare(flags) != 0:
            _no_mount_namespace = f"unshare failed: {first}"
            return f"unshare failed: {first}"
    if mount:
        # A tmpfs made in a user namespace refuses files for an owner it cannot map.
        ids = rootfs.write_id_maps(uid, gid) if own_user else None
        _no_mount_namespace = ids or rootfs.make_mounts_private()
    if not others:
        return None
    try:
        pid = os.fork()
    except OSError as exc:  # the namespaces exist but the PID one holds nobody: refuse
        _no_mount_namespace = "the PID namespace holds nobody"
        return f"fork into the new PID namespace failed: {exc.strerror or exc}"
    if pid:
        _wait_and_exit(pid)
    _own_pid_namespace = True
    return None


def isolate_filesystem(paths: list[str]) -> str | None:
    """Enter a root of its own holding only ``paths`` (read-only) and, as PID 1 of its own
    PID namespace, a fresh /proc (:func:`training.sandbox.rootfs.enter_private_root`): a
    lookup of anything else finds nothing. None when done, else why not."""
    if _no_mount_namespace is not None:
        return _no_mount_namespace
    return rootfs.enter_private_root(paths, with_proc=_own_pid_namespace)


_UNCATCHABLE = frozenset({signal.SIGKILL, signal.SIGSTOP})


def _wait_and_exit(pid: int) -> None:
    """In the process outside the PID namespace: close every descriptor (the pipes are the
    sandboxed process's alone), wait for it, and leave with its status, a signal as that
    signal (so the parent's words for a SIGSYS or a SIGKILL stay right)."""
    os.closerange(0, 1 << 16)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    while True:
        try:
            _, status = os.waitpid(pid, 0)
            break
        except ChildProcessError:
            os._exit(0)
        except InterruptedError:
            continue
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        if sig not in _UNCATCHABLE:  # signal.signal refuses these (EINVAL)
            signal.signal(sig, signal.SIG_DFL)
            os.kill(os.getpid(), sig)
        # SIGKILL itself (the CPU time's hard limit: the kernel spares a namespace's first
        # process the soft limit's SIGXCPU), or a signal whose default is to continue.
        os.kill(os.getpid(), signal.SIGKILL)
    os._exit(os.waitstatus_to_exitcode(status) & 0xFF)


def set_rlimits(
    *, cpu_seconds: int, memory_bytes: int, open_files: int, threads: bool
) -> str | None:
    """CPU, address space (current size + ``memory_bytes``), files, no file writes, no cores,
    no new processes (RLIMIT_NPROC 0; root in the initial user namespace is exempt), and few
    queued signals: RLIMIT_SIGPENDING bounds the real-time signals it queues and the POSIX
    timers it creates, both charged to the worker's uid across the host (issue 52)."""
    from training.sandbox.limits import MAX_PENDING_SIGNALS

    problems = []
    with open("/proc/self/statm") as f:
        vm_bytes = int(f.read().split()[0]) * resource.getpagesize()
    wanted = [
        (resource.RLIMIT_CPU, (cpu_seconds, cpu_seconds + 1)),
        (resource.RLIMIT_AS, (vm_bytes + memory_bytes,) * 2),
        (resource.RLIMIT_NOFILE, (open_files,) * 2),
        (resource.RLIMIT_FSIZE, (0, 0)),
        (resource.RLIMIT_CORE, (0, 0)),
        (resource.RLIMIT_MSGQUEUE, (0, 0)),
        (resource.RLIMIT_SIGPENDING, (MAX_PENDING_SIGNALS,) * 2),
    ]
    if not threads:
        wanted.append((resource.RLIMIT_NPROC, (0, 0)))
    for which, (soft, hard) in wanted:
        try:
            _, old_hard = resource.getrlimit(which)
            if old_hard != resource.RLIM_INFINITY:
                hard = min(hard, old_hard)
                soft = min(soft, hard)
            resource.setrlimit(which, (soft, hard))
        except (ValueError, OSError) as exc:
            problems.append(f"{which}: {exc}")
    return "; ".join(problems) or None


def set_no_new_privs() -> str | None:
    libc = _libc()
    if libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
        return f"prctl(NO_NEW_PRIVS) failed: {os.strerror(ctypes.get_errno())}"
    libc.prctl(PR_SET_DUMPABLE, 0, 0, 0, 0)  # no ptrace / /proc/<pid>/mem of us by others
    return None


def probe_limits_locked() -> str | None:
    """None when the hard limits cannot be raised again (tried on RLIMIT_NOFILE, then
    lowered back, which is always allowed); else why not."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY:
        return "the limits were not set"
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard + 1))
    except (ValueError, OSError):
        return None
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    return "the process can raise its hard limits (CAP_SYS_RESOURCE)"


def default_read_paths(extra: tuple[str, ...] = ()) -> list[str]:
    """Directories a locked-down child may read: the Python installation and its packages,
    our own packages, system libraries (for late imports of extension modules), and ``extra``."""
    here = Path(__file__).resolve()
    candidates = [sys.prefix, sys.base_prefix, sys.exec_prefix, sys.base_exec_prefix]
    candidates += [p for p in sys.path if p and "site-packages" in p or p.endswith("lib-dynload")]
    candidates += [str(here.parents[1]), str(here.parents[2] / "racing")]
    candidates += ["/usr/lib", "/usr/lib64", "/lib", "/lib64", "/usr/local/lib"]
    candidates += list(extra)
    seen: list[str] = []
    for path in candidates:
        real = os.path.realpath(path)
        if os.path.exists(real) and real not in seen and real != "/":
            seen.append(real)
    return seen


def apply_all(
    *,
    cpu_seconds: int,
    memory_bytes: int,
    open_files: int,
    allow_threads: bool,
    read_paths: tuple[str, ...],
    caller_uid: int,
    skip: frozenset[str] = frozenset(),
) -> LayerReport:
    """Apply rlimits, a root of its own (``mount_namespace``: only the read paths exist),
    no_new_privs, Landlock, seccomp (after imports); report each, and the
    protections they add up to: ``signal_scope`` (Landlock ABI 6), ``nproc_limit``
    (RLIMIT_NPROC binds a ``caller_uid`` other than root) and ``limits_locked`` (a probe).

    ``skip`` names layers not to apply (tests use it to show each layer holds alone).
    """
    report: LayerReport = {}

    def record(name: str, reason: str | None) -> None:
        report[name] = ACTIVE if reason is None else f"unavailable: {reason}"

    def run(name: str, fn: Callable[[], str | None]) -> str | None:
        if name in skip:
            report[name] = "disabled (test only)"
            return "disabled"
        reason = fn()
        record(name, reason)
        return reason

    run(
        "rlimits",
        lambda: set_rlimits(
            cpu_seconds=cpu_seconds,
            memory_bytes=memory_bytes,
            open_files=open_files,
            threads=allow_threads,
        ),
    )
    nproc_binds = report["rlimits"] == ACTIVE and not allow_threads and caller_uid != 0
    record("nproc_limit", None if nproc_binds else "root (or threads allowed) is not bound")
    # The same paths for both: what Landlock lets it open is all that exists in its root.
    paths = default_read_paths(read_paths)
    run("mount_namespace", lambda: isolate_filesystem(paths))
    nnp = set_no_new_privs()
    record("no_new_privs", nnp)
    if nnp is None:
        ll = run("landlock", lambda: landlock.restrict_to_read_only(paths))
        # Without Landlock nothing limits what is read: refuse every open() instead.
        run(
            "seccomp",
            lambda: seccomp.install_filter(allow_threads=allow_threads, deny_open=ll is not None),
        )
        if ll is not None and report.get("seccomp") == ACTIVE:
            report["seccomp"] = "active (all opens refused: no Landlock)"
    else:
        record("landlock", "needs no_new_privs")
        record("seccomp", "needs no_new_privs")
    bounded = report["rlimits"] == ACTIVE and report["seccomp"].startswith(ACTIVE)
    record("address_space_limit", None if bounded else "needs rlimits and seccomp")
    scoped = report["landlock"] == ACTIVE and landlock.abi_version() >= landlock.SCOPE_ABI
    record("signal_scope", None if scoped else "needs Landlock ABI 6")
    locked = probe_limits_locked() if report["rlimits"] == ACTIVE else "the limits were not set"
    record("limits_locked", locked)
    return report
