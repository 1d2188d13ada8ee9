"""A seccomp-bpf filter written directly (ctypes + the seccomp syscall), no libseccomp.

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
- signals to other processes: kill/tgkill only to the child itself.

Only x86_64 is described; elsewhere :func:`install_filter` reports the layer as unavailable.
"""

from __future__ import annotations

import ctypes
import errno
import os
import platform
import struct

AUDIT_ARCH_X86_64 = 0xC000003E
X32_SYSCALL_BIT = 0x40000000

SECCOMP_RET_KILL_PROCESS = 0x80000000
SECCOMP_RET_ERRNO = 0x00050000
SECCOMP_RET_ALLOW = 0x7FFF0000
SECCOMP_SET_MODE_FILTER = 1
SECCOMP_FILTER_FLAG_TSYNC = 1
NR_SECCOMP = 317

BPF_LD_W_ABS = 0x20
BPF_JEQ_K = 0x15
BPF_JGE_K = 0x35
BPF_JSET_K = 0x45
BPF_RET_K = 0x06

CLONE_THREAD = 0x00010000
OPEN_WRITE_FLAGS = (
    0o3 | 0o100 | 0o1000 | 0o2000 | 0o20000000
)  # WRONLY|RDWR|CREAT|TRUNC|APPEND|TMPFILE

# x86_64 numbers (asm/unistd_64.h).
DENIED_SYSCALLS: dict[str, int] = {
    "fork": 57, "vfork": 58, "execve": 59, "execveat": 322,
    "socket": 41, "connect": 42, "accept": 43, "bind": 49, "listen": 50, "socketpair": 53,
    "accept4": 288,
    "creat": 85, "unlink": 87, "unlinkat": 263, "rename": 82, "renameat": 264,
    "renameat2": 316, "mkdir": 83, "mkdirat": 258, "rmdir": 84, "link": 86, "linkat": 265,
    "symlink": 88, "symlinkat": 266, "chmod": 90, "fchmod": 91, "fchmodat": 268,
    "fchmodat2": 452, "chown": 92, "fchown": 93, "lchown": 94, "fchownat": 260,
    "truncate": 76, "ftruncate": 77, "mknod": 133, "mknodat": 259, "utime": 132,
    "utimes": 235, "utimensat": 280, "futimesat": 261, "setxattr": 188, "lsetxattr": 189,
    "fsetxattr": 190, "removexattr": 197, "lremovexattr": 198, "fremovexattr": 199,
    "mount": 165, "umount2": 166, "pivot_root": 155, "chroot": 161, "open_tree": 428,
    "move_mount": 429, "fsopen": 430, "fsconfig": 431, "fsmount": 432, "fspick": 433,
    "mount_setattr": 442, "unshare": 272, "setns": 308, "ptrace": 101,
    "process_vm_readv": 310, "process_vm_writev": 311, "process_madvise": 440,
    "kexec_load": 246, "kexec_file_load": 320, "init_module": 175, "finit_module": 313,
    "delete_module": 176, "bpf": 321, "perf_event_open": 298, "userfaultfd": 323,
    "keyctl": 250, "add_key": 248, "request_key": 249, "io_uring_setup": 425,
    "io_uring_enter": 426, "io_uring_register": 427, "memfd_create": 319, "memfd_secret": 447,
    "tkill": 200, "rt_sigqueueinfo": 129, "rt_tgsigqueueinfo": 297, "pidfd_open": 434,
    "pidfd_send_signal": 424, "pidfd_getfd": 438, "name_to_handle_at": 303,
    "open_by_handle_at": 304, "fanotify_init": 300, "sethostname": 170,
    "setdomainname": 171, "reboot": 169, "swapon": 167, "swapoff": 168, "acct": 163,
    "settimeofday": 164, "clock_settime": 227, "adjtimex": 159, "clock_adjtime": 305,
    "iopl": 172, "ioperm": 173, "quotactl": 179, "syslog": 103, "vhangup": 153,
    "setuid": 105, "setgid": 106, "setreuid": 113, "setregid": 114, "setresuid": 117,
    "setresgid": 119, "setgroups": 116, "capset": 126, "setsid": 112, "setpgid": 109,
}  # fmt: skip
NR_OPEN, NR_OPENAT, NR_OPENAT2 = 2, 257, 437
NR_CLONE, NR_CLONE3 = 56, 435
NR_KILL, NR_TGKILL = 62, 234


def _stmt(code: int, k: int) -> tuple[int, int, int, int]:
    return (code, 0, 0, k)


def _jump(code: int, k: int, jt: int, jf: int) -> tuple[int, int, int, int]:
    return (code, jt, jf, k)


def _arg_low(index: int) -> int:
    """Offset of the low 32 bits of syscall argument ``index`` in struct seccomp_data."""
    return 16 + 8 * index


def build_program(
    *, allow_threads: bool, deny_open: bool, own_pid: int
) -> list[tuple[int, int, int, int]]:
    """The BPF instructions (code, jt, jf, k) of the filter; see the module docstring."""
    eperm = SECCOMP_RET_ERRNO | errno.EPERM
    enosys = SECCOMP_RET_ERRNO | errno.ENOSYS
    prog = [
        _stmt(BPF_LD_W_ABS, 4),  # arch
        _jump(BPF_JEQ_K, AUDIT_ARCH_X86_64, 1, 0),
        _stmt(BPF_RET_K, SECCOMP_RET_KILL_PROCESS),
        _stmt(BPF_LD_W_ABS, 0),  # nr
        _jump(BPF_JGE_K, X32_SYSCALL_BIT, 0, 1),
        _stmt(BPF_RET_K, SECCOMP_RET_KILL_PROCESS),
    ]
    for nr in sorted(set(DENIED_SYSCALLS.values())):
        prog += [_jump(BPF_JEQ_K, nr, 0, 1), _stmt(BPF_RET_K, eperm)]
    for nr in (NR_CLONE3, NR_OPENAT2):
        prog += [_jump(BPF_JEQ_K, nr, 0, 1), _stmt(BPF_RET_K, enosys)]
    if deny_open:
        for nr in (NR_OPEN, NR_OPENAT):
            prog += [_jump(BPF_JEQ_K, nr, 0, 1), _stmt(BPF_RET_K, eperm)]
    else:
        for nr, flags_arg in ((NR_OPEN, 1), (NR_OPENAT, 2)):
            prog += [
                _jump(BPF_JEQ_K, nr, 0, 4),
                _stmt(BPF_LD_W_ABS, _arg_low(flags_arg)),
                _jump(BPF_JSET_K, OPEN_WRITE_FLAGS, 0, 1),
                _stmt(BPF_RET_K, eperm),
                _stmt(BPF_RET_K, SECCOMP_RET_ALLOW),
            ]
    if allow_threads:
        prog += [
            _jump(BPF_JEQ_K, NR_CLONE, 0, 4),
            _stmt(BPF_LD_W_ABS, _arg_low(0)),
            _jump(BPF_JSET_K, CLONE_THREAD, 0, 1),
            _stmt(BPF_RET_K, SECCOMP_RET_ALLOW),
            _stmt(BPF_RET_K, eperm),
        ]
    else:
        prog += [_jump(BPF_JEQ_K, NR_CLONE, 0, 1), _stmt(BPF_RET_K, eperm)]
    for nr in (NR_KILL, NR_TGKILL):  # the first argument must be our own pid
        prog += [
            _jump(BPF_JEQ_K, nr, 0, 4),
            _stmt(BPF_LD_W_ABS, _arg_low(0)),
            _jump(BPF_JEQ_K, own_pid, 0, 1),
            _stmt(BPF_RET_K, SECCOMP_RET_ALLOW),
            _stmt(BPF_RET_K, eperm),
        ]
    prog.append(_stmt(BPF_RET_K, SECCOMP_RET_ALLOW))
    return prog


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]


def supported() -> bool:
    return platform.system() == "Linux" and platform.machine() == "x86_64"


def install_filter(*, allow_threads: bool, deny_open: bool) -> str | None:
    """Install the filter on every thread of this process (TSYNC).

    Needs no_new_privs set first. Returns None on success or the reason it is not active.
    """
    if not supported():
        return f"no filter for {platform.machine()}"
    prog = build_program(allow_threads=allow_threads, deny_open=deny_open, own_pid=os.getpid())
    raw = b"".join(struct.pack("=HBBI", *ins) for ins in prog)
    buf = ctypes.create_string_buffer(raw, len(raw))
    fprog = _SockFprog(len(prog), ctypes.cast(buf, ctypes.c_void_p))
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    rc = libc.syscall(
        ctypes.c_long(NR_SECCOMP),
        ctypes.c_ulong(SECCOMP_SET_MODE_FILTER),
        ctypes.c_ulong(SECCOMP_FILTER_FLAG_TSYNC),
        ctypes.byref(fprog),
    )
    if rc != 0:
        err = ctypes.get_errno()
        return f"seccomp() failed: {os.strerror(err) if err else f'thread {rc} not synced'}"
    return None
