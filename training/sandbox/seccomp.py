"""The seccomp filter, built by libseccomp for whatever CPU this runs on (x86_64, aarch64, ...).

Why libseccomp, called through ctypes: it is the kept library every container runtime uses
(Docker, podman, systemd); it owns the per-architecture syscall tables, the BPF generation,
the architecture check and x86's x32 trap, so one list of syscall *names* works on x86_64 and
aarch64 alike (the hand-made BPF this replaces knew x86_64 numbers only). Its C library is
part of every Debian/Ubuntu system (``libseccomp2``: apt and systemd depend on it), so there is
nothing to build. We bind its stable C API directly (eight functions) rather than through
``pyseccomp``: that package (last released 2021) runs ``ldconfig`` in a subprocess when it is
imported, which a child confined to a one-process cgroup cannot do; the official bindings
(Debian's python3-seccomp) live outside the virtualenv. bubblewrap was not chosen: it is not
installed everywhere, and the child already does what it would (namespaces, no_new_privs).
Without libseccomp the layer reports itself unavailable and the sandbox fails closed
(:mod:`training.sandbox.requirements`).

The filter is a deny-list: everything not named here is allowed, because the child runs
CPython, numpy and (for rollouts) PyBullet and torch, whose syscalls are many. What it refuses
(EPERM, so Python raises a clean OSError):

- new processes and programs: fork, vfork, execve, execveat, clone without CLONE_THREAD
  (with it too unless threads are allowed); clone3 gets ENOSYS so glibc falls back to clone;
- the network: socket, socketpair, connect, bind, listen, accept;
- writing the filesystem: open/openat with any write, create, truncate or append flag,
  creat, unlink, rename, mkdir, link, chmod, chown, truncate, xattrs, mknod, utimes;
  with ``deny_open`` every open at all (the fallback for kernels without Landlock);
- leaving or widening the box: unshare, setns, mount family, chroot, ptrace,
  process_vm_*, bpf, perf_event_open, io_uring (it bypasses seccomp), userfaultfd, keyctl,
  module loading, kexec, reboot, clock setting, memfd_create, open_by_handle_at;
- its own limits and fate: setrlimit, prlimit64 with a new limit, and
  prctl(PR_SET_PDEATHSIG) (it cannot stop dying with its parent);
- signals to other processes: kill/tgkill only to the child itself;
- other processes' scheduling: setpriority, sched_setscheduler/setparam/setattr/setaffinity,
  ioprio_set, prlimit64 and migrate_pages/move_pages on any process but itself (pid 0);
- memory outside its address space: System V shared memory, message queues and semaphores,
  POSIX message queues (with memfd_create above: nothing it holds escapes RLIMIT_AS);
- shrinking its pipes (fcntl F_SETPIPE_SZ), which could stall a parent writing to it;
- what the worker's user shares with every other process of that user on the host (issue 52):
  inotify (``inotify_init``/``inotify_init1``/``inotify_add_watch``: instances and watches are
  counted per uid across the host, and a watch reports names of files created and opened in
  folders Landlock keeps it from reading) and fanotify; the page cache of files others read
  (``fadvise64`` of any kind, ``madvise`` with MADV_PAGEOUT, MADV_COLD, MADV_REMOVE,
  MADV_HWPOISON, MADV_SOFT_OFFLINE or MADV_MERGEABLE: DONTNEED and FREE, which malloc uses,
  only drop the caller's own mapping); and disk reads that skip the page cache (open/openat
  with O_DIRECT, ``fcntl(F_SETFL, O_DIRECT)``; openat2 gets ENOSYS so libc uses openat), so
  its reads go through the cache, where its memory cgroup bounds them, and its I/O cgroup
  (:mod:`training.sandbox.cgroup`) paces them. POSIX timers are left to RLIMIT_SIGPENDING
  (:func:`training.sandbox.lockdown.set_rlimits`): each one is charged to it.

A name the installed libseccomp does not know (a syscall newer than it) is skipped: Landlock
still covers the filesystem ones; keeping libseccomp2 updated keeps the list whole.
"""

from __future__ import annotations

import ctypes
import errno
import os
from functools import cache

LIBRARY = "libseccomp.so.2"
SCMP_ACT_ALLOW = 0x7FFF0000
SCMP_FLTATR_CTL_TSYNC = 4
SCMP_CMP_NE, SCMP_CMP_EQ, SCMP_CMP_MASKED_EQ = 1, 4, 7
SCMP_ARCH_X86_64 = 0xC000003E
SCMP_ARCH_AARCH64 = 0xC00000B7
CLONE_THREAD = 0x00010000
PR_SET_PDEATHSIG = 1
#: open flags that write: any one of them set refuses the open.
OPEN_WRITE_FLAGS = (os.O_WRONLY, os.O_RDWR, os.O_CREAT, os.O_TRUNC, os.O_APPEND, 0o20000000)

DENIED_SYSCALLS: tuple[str, ...] = (
    "fork", "vfork", "execve", "execveat",
    "socket", "connect", "accept", "accept4", "bind", "listen", "socketpair",
    "creat", "unlink", "unlinkat", "rename", "renameat", "renameat2", "mkdir", "mkdirat",
    "rmdir", "link", "linkat", "symlink", "symlinkat", "chmod", "fchmod", "fchmodat",
    "fchmodat2", "chown", "fchown", "lchown", "fchownat", "truncate", "ftruncate", "mknod",
    "mknodat", "utime", "utimes", "utimensat", "futimesat", "setxattr", "lsetxattr",
    "fsetxattr", "removexattr", "lremovexattr", "fremovexattr",
    "mount", "umount2", "pivot_root", "chroot", "open_tree", "move_mount", "fsopen",
    "fsconfig", "fsmount", "fspick", "mount_setattr", "unshare", "setns", "ptrace",
    "process_vm_readv", "process_vm_writev", "process_madvise", "kexec_load",
    "kexec_file_load", "init_module", "finit_module", "delete_module", "bpf",
    "perf_event_open", "userfaultfd", "keyctl", "add_key", "request_key", "io_uring_setup",
    "io_uring_enter", "io_uring_register", "memfd_create", "memfd_secret", "tkill",
    "rt_sigqueueinfo", "rt_tgsigqueueinfo", "pidfd_open", "pidfd_send_signal", "pidfd_getfd",
    "name_to_handle_at", "open_by_handle_at", "fanotify_init", "fanotify_mark",
    "inotify_init", "inotify_init1", "inotify_add_watch", "fadvise64", "fadvise64_64",
    "sethostname",
    "setdomainname", "reboot", "swapon", "swapoff", "acct", "settimeofday", "clock_settime",
    "adjtimex", "clock_adjtime", "iopl", "ioperm", "quotactl", "syslog", "vhangup",
    "setuid", "setgid", "setreuid", "setregid", "setresuid", "setresgid", "setgroups",
    "capset", "setsid", "setpgid", "setrlimit",
    "shmget", "shmat", "shmctl", "shmdt", "msgget", "msgsnd", "msgrcv", "msgctl", "semget",
    "semop", "semtimedop", "semctl", "mq_open", "mq_unlink", "mq_timedsend",
    "mq_timedreceive", "mq_notify", "mq_getsetattr", "kcmp",
)  # fmt: skip
#: Calls whose first argument names a process (0: the caller), refused for any other.
PID_FIRST_SYSCALLS: tuple[str, ...] = (
    "sched_setaffinity", "sched_setscheduler", "sched_setparam", "sched_setattr",
    "prlimit64", "migrate_pages", "move_pages",
)  # fmt: skip
PRIO_PROCESS = 0
IOPRIO_WHO_PROCESS = 1
F_SETPIPE_SZ = 1031
F_SETFL = 4
#: O_DIRECT differs between CPUs (asm/fcntl.h); None stands for the one this runs on.
O_DIRECT_BY_ARCH: dict[int | None, int] = {
    SCMP_ARCH_X86_64: 0o40000,
    SCMP_ARCH_AARCH64: 0o200000,
    None: getattr(os, "O_DIRECT", 0o40000),
}
#: madvise advice that acts on pages other processes share (the page cache of a file, KSM) or
#: on the machine's memory itself: PAGEOUT, COLD, REMOVE, MERGEABLE, HWPOISON, SOFT_OFFLINE.
REFUSED_MADVISE: dict[str, int] = {
    "MADV_REMOVE": 9,
    "MADV_MERGEABLE": 12,
    "MADV_COLD": 20,
    "MADV_PAGEOUT": 21,
    "MADV_HWPOISON": 100,
    "MADV_SOFT_OFFLINE": 101,
}


class _ArgCmp(ctypes.Structure):
    _fields_ = [
        ("arg", ctypes.c_uint),
        ("op", ctypes.c_int),
        ("datum_a", ctypes.c_uint64),
        ("datum_b", ctypes.c_uint64),
    ]


@cache
def library() -> ctypes.CDLL | None:
    """libseccomp, loaded by soname (no subprocess, no search path); None when absent.
    Called before lock-down, while the library file can still be read."""
    try:
        lib = ctypes.CDLL(LIBRARY, use_errno=True)
    except OSError:
        return None
    lib.seccomp_init.argtypes = (ctypes.c_uint32,)
    lib.seccomp_init.restype = ctypes.c_void_p
    lib.seccomp_release.argtypes = (ctypes.c_void_p,)
    lib.seccomp_release.restype = None
    lib.seccomp_load.argtypes = (ctypes.c_void_p,)
    lib.seccomp_attr_set.argtypes = (ctypes.c_void_p, ctypes.c_int, ctypes.c_uint32)
    lib.seccomp_arch_add.argtypes = (ctypes.c_void_p, ctypes.c_uint32)
    lib.seccomp_arch_remove.argtypes = (ctypes.c_void_p, ctypes.c_uint32)
    lib.seccomp_arch_native.restype = ctypes.c_uint32
    lib.seccomp_syscall_resolve_name.argtypes = (ctypes.c_char_p,)
    lib.seccomp_rule_add_array.argtypes = (
        ctypes.c_void_p,
        ctypes.c_uint32,
        ctypes.c_int,
        ctypes.c_uint,
        ctypes.POINTER(_ArgCmp),
    )
    lib.seccomp_export_pfc.argtypes = (ctypes.c_void_p, ctypes.c_int)
    return lib


def supported() -> bool:
    return library() is not None


def _errno_action(code: int) -> int:
    return 0x00050000 | (code & 0xFFFF)  # SCMP_ACT_ERRNO


class _Filter:
    """A libseccomp filter context; ``rule`` adds one, skipping syscalls the CPU lacks."""

    def __init__(self, lib: ctypes.CDLL, arch: int | None) -> None:
        self.lib = lib
        self.ctx = lib.seccomp_init(SCMP_ACT_ALLOW)
        if not self.ctx:
            raise OSError(errno.ENOMEM, "seccomp_init failed")
        if arch is not None and arch != lib.seccomp_arch_native():
            self._check(lib.seccomp_arch_add(self.ctx, arch))
            self._check(lib.seccomp_arch_remove(self.ctx, lib.seccomp_arch_native()))

    @staticmethod
    def _check(rc: int) -> None:
        if rc < 0:
            raise OSError(-rc, os.strerror(-rc))

    def rule(self, action: int, name: str, *cmps: tuple[int, int, int, int]) -> None:
        nr = self.lib.seccomp_syscall_resolve_name(name.encode())
        if nr == -1:  # __NR_SCMP_ERROR: a name libseccomp does not know
            return
        array = (_ArgCmp * max(1, len(cmps)))(*[_ArgCmp(*c) for c in cmps])
        rc = self.lib.seccomp_rule_add_array(self.ctx, action, nr, len(cmps), array)
        if rc not in (0, -errno.EDOM):  # EDOM: no such syscall on this architecture
            self._check(rc)

    def release(self) -> None:
        self.lib.seccomp_release(self.ctx)


def _int_eq(arg: int, value: int) -> tuple[int, int, int, int]:
    """Argument ``arg`` equals ``value`` in its low 32 bits. The kernel reads an ``int``
    argument (fcntl's command, madvise's advice, prctl's option) from the low half of the
    register: a plain 64-bit EQ would let ``value | 1 << 32`` through to the same call."""
    return (arg, SCMP_CMP_MASKED_EQ, 0xFFFFFFFF, value)


def _build(
    lib: ctypes.CDLL, *, allow_threads: bool, deny_open: bool, own_pid: int, arch: int | None
) -> _Filter:
    f = _Filter(lib, arch)
    eperm = _errno_action(errno.EPERM)
    try:
        for name in DENIED_SYSCALLS:
            f.rule(eperm, name)
        for name in ("clone3", "openat2"):
            f.rule(_errno_action(errno.ENOSYS), name)
        o_direct = O_DIRECT_BY_ARCH.get(arch, O_DIRECT_BY_ARCH[None])
        for name, flags_arg in (("open", 1), ("openat", 2)):
            if deny_open:
                f.rule(eperm, name)
                continue
            for flag in (*OPEN_WRITE_FLAGS, o_direct):
                f.rule(eperm, name, (flags_arg, SCMP_CMP_MASKED_EQ, flag, flag))
        f.rule(eperm, "fcntl", _int_eq(1, F_SETFL), (2, SCMP_CMP_MASKED_EQ, o_direct, o_direct))
        for advice in REFUSED_MADVISE.values():
            f.rule(eperm, "madvise", _int_eq(2, advice))
        if allow_threads:
            f.rule(eperm, "clone", (0, SCMP_CMP_MASKED_EQ, CLONE_THREAD, 0))
        else:
            f.rule(eperm, "clone")
        f.rule(eperm, "prlimit64", (2, SCMP_CMP_NE, 0, 0))  # setting, not reading, a limit
        for name in PID_FIRST_SYSCALLS:
            f.rule(eperm, name, (0, SCMP_CMP_NE, 0, 0))
        # setpriority(which, who, nice) and ioprio_set(which, who, prio): only the caller, by
        # 0 (rules on one syscall are OR-ed: a wrong ``which`` or a named ``who`` is refused).
        for name, which in (("setpriority", PRIO_PROCESS), ("ioprio_set", IOPRIO_WHO_PROCESS)):
            f.rule(eperm, name, (0, SCMP_CMP_NE, which, 0))
            f.rule(eperm, name, (1, SCMP_CMP_NE, 0, 0))
        f.rule(eperm, "fcntl", _int_eq(1, F_SETPIPE_SZ))
        f.rule(eperm, "prctl", _int_eq(0, PR_SET_PDEATHSIG))
        for name in ("kill", "tgkill"):  # the first argument must be our own pid
            f.rule(eperm, name, (0, SCMP_CMP_NE, own_pid, 0))
    except BaseException:
        f.release()
        raise
    return f


def filter_text(*, arch: int, allow_threads: bool = False, deny_open: bool = False) -> str:
    """The filter libseccomp would build for ``arch`` (an SCMP_ARCH_* token), in its
    human-readable PFC form: lets tests check the aarch64 filter on an x86_64 machine."""
    lib = library()
    if lib is None:
        raise OSError(errno.ENOENT, f"{LIBRARY} is not installed")
    f = _build(lib, allow_threads=allow_threads, deny_open=deny_open, own_pid=1, arch=arch)
    fd = os.memfd_create("racecraft-seccomp-pfc", os.MFD_CLOEXEC)
    try:
        f._check(lib.seccomp_export_pfc(f.ctx, fd))
        os.lseek(fd, 0, os.SEEK_SET)
        with os.fdopen(os.dup(fd), "r") as text:
            return text.read()
    finally:
        f.release()
        os.close(fd)


def install_filter(*, allow_threads: bool, deny_open: bool) -> str | None:
    """Install the filter on every thread of this process (TSYNC).

    Needs no_new_privs set first. Returns None on success or the reason it is not active.
    """
    lib = library()
    if lib is None:
        return f"{LIBRARY} not found (apt-get install libseccomp2)"
    try:
        f = _build(
            lib, allow_threads=allow_threads, deny_open=deny_open, own_pid=os.getpid(), arch=None
        )
    except OSError as exc:
        return f"building the filter failed: {exc.strerror or exc}"
    try:
        f._check(lib.seccomp_attr_set(f.ctx, SCMP_FLTATR_CTL_TSYNC, 1))
        f._check(lib.seccomp_load(f.ctx))
    except OSError as exc:
        return f"seccomp_load failed: {exc.strerror or exc}"
    finally:
        f.release()
    return None
