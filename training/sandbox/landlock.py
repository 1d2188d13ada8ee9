"""Landlock (Linux >= 5.13): read-only access to a few directories, nothing else.

Applied with the raw syscalls through ctypes. The ruleset handles every filesystem right the
kernel's ABI knows, so any access not granted below is refused: no writes anywhere, reads only
beneath the given directories. ABI >= 4 also refuses TCP bind/connect; ABI >= 6 scopes
signals and abstract unix sockets to the sandbox (it cannot signal its parent).
Landlock applies to the calling thread and its future children only; the child locks down on
its main thread, which is the one that runs user code.
"""

from __future__ import annotations

import ctypes
import os

NR_CREATE_RULESET, NR_ADD_RULE, NR_RESTRICT_SELF = 444, 445, 446
CREATE_RULESET_VERSION = 1
RULE_PATH_BENEATH = 1

FS_EXECUTE = 1 << 0
FS_READ_FILE = 1 << 2
FS_READ_DIR = 1 << 3
_FS_ALL_BY_ABI = {1: (1 << 13) - 1, 2: (1 << 14) - 1, 3: (1 << 15) - 1, 5: (1 << 16) - 1}
NET_BIND_TCP, NET_CONNECT_TCP = 1 << 0, 1 << 1
SCOPE_ABSTRACT_UNIX_SOCKET, SCOPE_SIGNAL = 1 << 0, 1 << 1
#: First ABI that scopes signals and abstract unix sockets.
SCOPE_ABI = 6


class _RulesetAttr(ctypes.Structure):
    _fields_ = [
        ("handled_access_fs", ctypes.c_uint64),
        ("handled_access_net", ctypes.c_uint64),
        ("scoped", ctypes.c_uint64),
    ]


class _PathBeneathAttr(ctypes.Structure):
    _pack_ = 1
    _fields_ = [("allowed_access", ctypes.c_uint64), ("parent_fd", ctypes.c_int32)]


def _libc() -> ctypes.CDLL:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    return libc


def abi_version() -> int:
    """Landlock ABI of the running kernel, 0 when unavailable."""
    rc = _libc().syscall(
        ctypes.c_long(NR_CREATE_RULESET),
        None,
        ctypes.c_size_t(0),
        ctypes.c_uint32(CREATE_RULESET_VERSION),
    )
    return max(int(rc), 0)


def _fs_all(abi: int) -> int:
    best = max(k for k in _FS_ALL_BY_ABI if k <= abi)
    return _FS_ALL_BY_ABI[best]


def restrict_to_read_only(paths: list[str]) -> str | None:
    """Forbid all filesystem access except reading beneath ``paths`` (existing dirs/files).

    Needs no_new_privs. Returns None on success or the reason the layer is not active.
    """
    abi = abi_version()
    if abi < 1:
        return "Landlock not supported by this kernel"
    libc = _libc()
    attr = _RulesetAttr(_fs_all(abi), 0, 0)
    size = 8
    if abi >= 4:
        attr.handled_access_net = NET_BIND_TCP | NET_CONNECT_TCP
        size = 16
    if abi >= SCOPE_ABI:
        attr.scoped = SCOPE_ABSTRACT_UNIX_SOCKET | SCOPE_SIGNAL
        size = 24
    ruleset = libc.syscall(
        ctypes.c_long(NR_CREATE_RULESET),
        ctypes.byref(attr),
        ctypes.c_size_t(size),
        ctypes.c_uint32(0),
    )
    if ruleset < 0:
        return f"landlock_create_ruleset failed: {os.strerror(ctypes.get_errno())}"
    try:
        for path in paths:
            try:
                fd = os.open(path, os.O_PATH | os.O_CLOEXEC)
            except OSError:
                continue
            try:
                is_dir = os.path.isdir(path)
                access = FS_READ_FILE | (FS_READ_DIR if is_dir else 0)
                rule = _PathBeneathAttr(access, fd)
                rc = libc.syscall(
                    ctypes.c_long(NR_ADD_RULE),
                    ctypes.c_int(ruleset),
                    ctypes.c_int(RULE_PATH_BENEATH),
                    ctypes.byref(rule),
                    ctypes.c_uint32(0),
                )
                if rc != 0:
                    return f"landlock_add_rule({path}) failed: {os.strerror(ctypes.get_errno())}"
            finally:
                os.close(fd)
        rc = libc.syscall(
            ctypes.c_long(NR_RESTRICT_SELF), ctypes.c_int(ruleset), ctypes.c_uint32(0)
        )
        if rc != 0:
            return f"landlock_restrict_self failed: {os.strerror(ctypes.get_errno())}"
    finally:
        os.close(ruleset)
    return None
