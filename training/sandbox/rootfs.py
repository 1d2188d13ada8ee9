"""The sandbox's own view of the filesystem: a root of its own holding only what it may read.

Landlock refuses to *open* anything outside the read paths, but looking a name up is not a
Landlock right: ``stat()``, ``access()`` and ``readlink()`` found ``/etc/shadow`` (its size and
time), the project's ``var/secret_key`` and, through the host's ``/proc``, every host process
by pid (issue 52). So the child gets a mount namespace (made by
:func:`training.sandbox.lockdown.unshare_namespaces` with the other namespaces, while the
process is single-threaded) and, at lock-down, :func:`enter_private_root` builds its root:

- a small tmpfs (read-only once built) becomes ``/`` (``pivot_root``), and the old root is
  unmounted, so nothing of the host is reachable by any path;
- each read path (:func:`training.sandbox.lockdown.default_read_paths`, the very list Landlock
  allows: the interpreter's prefix and stdlib, site-packages, our packages, the system
  library directories) is bind-mounted read-only at its own path, with the top-level symlinks
  that point into them (``/lib -> usr/lib``), so late imports and ``dlopen`` still resolve;
- ``/proc`` is a fresh one of the child's own PID namespace (it is that namespace's PID 1 by
  then), where no host process has a pid; where the kernel refuses it (a container that masks
  parts of the host's ``/proc``) there is no ``/proc`` at all;
- no ``/dev``: the inherited descriptors (pipes, the heartbeat, 0-2 on ``/dev/null``) stay
  open, and Python takes randomness from ``getrandom()``; Landlock refused every device
  anyway;
- last, the process drops every capability it held in its user namespace (the uid map the
  tmpfs needs would otherwise let them apply to the files it owns).
"""

from __future__ import annotations

import ctypes
import os

MS_RDONLY = 0x1
MS_NOSUID = 0x2
MS_NODEV = 0x4
MS_NOEXEC = 0x8
MS_REMOUNT = 0x20
MS_NOATIME = 0x400
MS_NODIRATIME = 0x800
MS_BIND = 0x1000
MS_REC = 0x4000
MS_PRIVATE = 0x40000
MS_RELATIME = 0x200000
MNT_DETACH = 0x2
#: statvfs's flags -> mount's: a read-only remount of a bind mount in a user namespace must
#: keep the flags its source was mounted with (the kernel locks them).
_LOCKED_FLAGS = (
    (os.ST_NOSUID, MS_NOSUID),
    (os.ST_NODEV, MS_NODEV),
    (os.ST_NOEXEC, MS_NOEXEC),
    (os.ST_NOATIME, MS_NOATIME),
    (os.ST_NODIRATIME, MS_NODIRATIME),
    (os.ST_RELATIME, MS_RELATIME),
)
_PIVOT_ROOT = {"x86_64": 155, "aarch64": 41, "riscv64": 41}.get(os.uname().machine)
#: Where the tmpfs is mounted before it becomes the root: a directory every system has. The
#: host's own /tmp stays reachable under the old root while the binds are made.
BASE = "/tmp"
OLD_ROOT = "/.old-root"
#: The new root's size: directories and empty mount points only.
TMPFS_OPTIONS = b"size=1m,nr_inodes=4096,mode=0755"
_CAP_VERSION_3 = 0x20080522


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [
        ("effective", ctypes.c_uint32),
        ("permitted", ctypes.c_uint32),
        ("inheritable", ctypes.c_uint32),
    ]


def _libc() -> ctypes.CDLL:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    return libc


def _check(rc: int, what: str) -> None:
    if rc != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


def _mount(source: str | None, target: str, fstype: str | None, flags: int, data=None) -> None:
    rc = _libc().mount(
        source.encode() if source else None,
        target.encode(),
        fstype.encode() if fstype else None,
        ctypes.c_ulong(flags),
        data,
    )
    _check(rc, f"mount {target}")


def make_mounts_private() -> str | None:
    """Stop mounts made from here on from propagating to the host's namespace (and back):
    right after ``unshare(CLONE_NEWNS)``, before any other mount."""
    try:
        _mount(None, "/", None, MS_REC | MS_PRIVATE)
    except OSError as exc:
        return str(exc.strerror)
    return None


def write_id_maps(uid: int, gid: int) -> str | None:
    """Map the caller's own uid and gid into the user namespace it has just made (the only
    mapping an unprivileged process may write): a tmpfs made in the namespace refuses to
    create files for an owner it cannot map (EOVERFLOW). The ids stay what they were."""
    try:
        for name, text in (("setgroups", "deny"), ("uid_map", f"{uid} {uid} 1")):
            with open(f"/proc/self/{name}", "w") as f:
                f.write(text)
        with open("/proc/self/gid_map", "w") as f:
            f.write(f"{gid} {gid} 1")
    except OSError as exc:
        return f"writing the user namespace's id maps failed: {exc.strerror or exc}"
    return None


def outermost(paths: list[str]) -> list[str]:
    """``paths`` less those inside another of them (a recursive bind brings them along)."""
    kept: list[str] = []
    for path in sorted(set(paths)):
        if not any(path == k or path.startswith(k.rstrip("/") + "/") for k in kept):
            kept.append(path)
    return kept


def _bind_read_only(source: str, target: str) -> None:
    if os.path.isdir(source):
        os.makedirs(target, exist_ok=True)
    else:
        os.makedirs(os.path.dirname(target), exist_ok=True)
        os.close(os.open(target, os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o444))
    _mount(source, target, None, MS_BIND | MS_REC)
    locked = os.statvfs(target).f_flag
    keep = 0
    for st_flag, ms_flag in _LOCKED_FLAGS:
        if locked & st_flag:
            keep |= ms_flag
    _mount(None, target, None, MS_REMOUNT | MS_BIND | MS_RDONLY | MS_NOSUID | keep)


def _link_aliases(old_root: str, bound: list[str]) -> None:
    """The old root's top-level symlinks into what is bound (``/lib -> usr/lib``, ``/lib64``,
    ``/bin``): what was read through them before still resolves."""
    for name in sorted(os.listdir(old_root)):
        link = os.path.join(old_root, name)
        if not os.path.islink(link) or os.path.lexists("/" + name):
            continue
        target = os.readlink(link)
        resolved = os.path.normpath(os.path.join("/", target))
        if any(resolved == b or resolved.startswith(b + "/") for b in bound):
            os.symlink(target, "/" + name)


def drop_capabilities() -> str | None:
    """Clear the effective, permitted and inheritable capability sets (no execve follows, so
    nothing gives them back)."""
    header = _CapHeader(_CAP_VERSION_3, 0)
    data = (_CapData * 2)()
    if _libc().capset(ctypes.byref(header), data) != 0:
        return f"capset failed: {os.strerror(ctypes.get_errno())}"
    return None


def enter_private_root(paths: list[str], *, with_proc: bool) -> str | None:
    """Make a fresh read-only root holding ``paths`` (existing, absolute, resolved) bound
    read-only at their own places, ``/proc`` of the caller's PID namespace when ``with_proc``,
    and nothing else; then drop every capability. Must run in a mount namespace of the
    caller's own whose mounts are private (:func:`make_mounts_private`). Returns None when
    done, else why not (the process may then be left in a partial root: it must not run user
    code unless weak isolation was accepted)."""
    if _PIVOT_ROOT is None:
        return f"pivot_root's number on {os.uname().machine} is not known here"
    libc = _libc()
    try:
        _mount("tmpfs", BASE, "tmpfs", MS_NOSUID | MS_NODEV, TMPFS_OPTIONS)
        os.mkdir(BASE + OLD_ROOT, 0o700)
        rc = libc.syscall(ctypes.c_long(_PIVOT_ROOT), BASE.encode(), (BASE + OLD_ROOT).encode())
        _check(rc, "pivot_root")
        os.chdir("/")
        bound = outermost(paths)
        for path in bound:
            _bind_read_only(OLD_ROOT + path, path)
        _link_aliases(OLD_ROOT, bound)
        if with_proc:
            os.mkdir("/proc", 0o555)
            try:
                _mount("proc", "/proc", "proc", MS_NOSUID | MS_NODEV | MS_NOEXEC)
            except OSError:  # a masked host /proc: better none than the host's
                os.rmdir("/proc")
        _check(libc.umount2(OLD_ROOT.encode(), MNT_DETACH), "umount the old root")
        os.rmdir(OLD_ROOT)
        _mount(None, "/", None, MS_REMOUNT | MS_BIND | MS_RDONLY | MS_NOSUID | MS_NODEV)
    except OSError as exc:
        return f"building its root failed: {exc.strerror or exc}"
    return drop_capabilities()
