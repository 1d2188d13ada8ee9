"""Issue 52, kernel layers part A: what the worker's uid shares with every other process of
that uid on the host, tried through the real sandbox with the Python guard off, and measured
from outside it: inotify instances (a bystander of the same uid opens its own while the child
holds what it could get), queued signals and POSIX timers (the uid's count in this process's
``SigQ``, and a bystander's ``timer_create`` under a limit just above it), the page cache of a
file this process reads (``mincore`` before and after), and the disk (a cold file read
through the child's I/O cgroup takes at least its size over the limit).

Each check that a refusal holds has a control beside it where that is cheap: the same attack
with seccomp off (weak isolation accepted, tests only) does reach the host, so the measurement
would see a regression.
"""

from __future__ import annotations

import ast
import ctypes
import errno
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from django.core.checks import ERROR

from tests.training.sandbox.sandbox_support import host_intact
from training import checks
from training.sandbox import SandboxLimits, SandboxProcess, evaluate_reward, seccomp
from training.sandbox.cgroup import IoCgroup, block_devices
from training.sandbox.limits import MAX_PENDING_SIGNALS
from training.sandbox.requirements import (
    ALLOW_WEAK_ENV,
    REQUIREMENTS,
    SIMULATE_ENV,
    missing_requirements,
)

TARGET = "tests.training.sandbox.shared_limits_target:hold"
LIMITS = SandboxLimits(per_call_seconds=20.0, cpu_seconds=60, start_seconds=60.0)
PAGE = os.sysconf("SC_PAGE_SIZE")
#: (madvise, fcntl, openat2) by CPU, from each architecture's unistd.h.
SYSCALL_NUMBERS = {"x86_64": (28, 72, 437), "aarch64": (233, 25, 437)}
IN_CLOEXEC = 0o2000000
IN_CREATE, IN_OPEN = 0x100, 0x20

_libc = ctypes.CDLL(None, use_errno=True)
_libc.mmap.restype = ctypes.c_void_p
_libc.mmap.argtypes = (
    ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_long,
)  # fmt: skip
_libc.munmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t)
_libc.mincore.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p)


class Held:
    """A sandbox child running :data:`TARGET`: ``report()`` is what the reward printed in the
    current phase (a dict), ``go()`` starts the next phase."""

    def __init__(self, sandbox: SandboxProcess) -> None:
        self.sandbox = sandbox

    def report(self) -> dict[str, Any]:
        msg = self.sandbox.recv(LIMITS.per_call_seconds + 10)
        assert msg.kind == "message", msg
        return ast.literal_eval(str(msg.value).strip().splitlines()[-1])

    def go(self) -> None:
        self.sandbox.send("go")


@contextmanager
def held(
    source: str, phases: list[str], *, disabled: tuple[str, ...] = (), weak: bool = False
) -> Iterator[Held]:
    sandbox = SandboxProcess(
        target=TARGET,
        reward_source=source,
        args={"phases": phases},
        limits=LIMITS,
        python_guards=False,
        disabled_layers=disabled,
        allow_weak=weak,
    )
    sandbox.start()
    try:
        yield Held(sandbox)
    finally:
        sandbox.close()


# -- inotify ---------------------------------------------------------------------------------

INOTIFY = """
import ctypes

libc = ctypes.CDLL(None, use_errno=True)
HELD = []

def reward_function(params):
    errors, watches = set(), 0
    for _ in range(40):
        fd = libc.inotify_init1(0)
        if fd < 0:
            errors.add(ctypes.get_errno())
            continue
        HELD.append(fd)
        for path in (b"/", b"/tmp", b"/etc", b"/proc/1"):
            if libc.inotify_add_watch(fd, path, 0x100 | 0x20) >= 0:   # IN_CREATE | IN_OPEN
                watches += 1
    fan = libc.fanotify_init(0, 0)
    print(repr({"instances": len(HELD), "watches": watches, "errors": sorted(errors),
                "fanotify": 0 if fan >= 0 else ctypes.get_errno()}))
    return 1.0
"""


def _bystander_inotify(folder: Path, count: int = 5) -> int:
    """How many of ``count`` inotify instances, each watching ``folder``, this process (the
    child's uid, outside the sandbox) gets; all are closed again."""
    got = 0
    for _ in range(count):
        fd = _libc.inotify_init1(IN_CLOEXEC)
        if fd < 0:
            continue
        try:
            if _libc.inotify_add_watch(fd, str(folder).encode(), IN_CREATE) >= 0:
                got += 1
        finally:
            os.close(fd)
    return got


def test_inotify_is_refused_and_a_bystander_of_the_uid_keeps_its_share(tmp_path: Path) -> None:
    with host_intact(), held(INOTIFY, ["grab"]) as child:
        grabbed = child.report()
        assert grabbed == {"instances": 0, "watches": 0, "errors": [errno.EPERM],
                           "fanotify": errno.EPERM}  # fmt: skip
        assert _bystander_inotify(tmp_path) == 5  # while the child is still there
        assert child.sandbox.layers["seccomp"] == "active"


def test_without_seccomp_the_child_would_hold_the_uids_inotify(tmp_path: Path) -> None:
    """The control: the kernel itself gives the child the uid's instances and watches on
    folders Landlock keeps it from reading; only seccomp stands in the way."""
    with held(INOTIFY, ["grab"], disabled=("seccomp",), weak=True) as child:
        grabbed = child.report()
        assert "no_host_watch" in child.sandbox.weak
    assert grabbed["instances"] > 0 and grabbed["watches"] > 0, grabbed


# -- queued signals and POSIX timers ---------------------------------------------------------

SIGNALS = """
import ctypes, os, resource, signal

libc = ctypes.CDLL(None, use_errno=True)
TIMERS = []

def reward_function(params):
    phase = params["phase"]
    out = {"phase": phase}
    if phase == "timers":
        out["limit"] = resource.getrlimit(resource.RLIMIT_SIGPENDING)
        out["errno"] = 0
        for _ in range(20000):
            tid = ctypes.c_void_p()
            if libc.timer_create(1, None, ctypes.byref(tid)) != 0:   # CLOCK_MONOTONIC
                out["errno"] = ctypes.get_errno()
                break
            TIMERS.append(tid)
        out["timers"] = len(TIMERS)
    elif phase == "signals":
        for tid in TIMERS:
            libc.timer_delete(tid)
        TIMERS.clear()
        signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGRTMIN])
        for _ in range(20000):
            os.kill(os.getpid(), signal.SIGRTMIN)
    else:
        queued = 0
        while signal.sigtimedwait([signal.SIGRTMIN], 0) is not None:
            queued += 1
        out["queued"] = queued
    print(repr(out))
    return 1.0
"""

BYSTANDER_TIMERS = """
import ctypes, resource, sys
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_SIGPENDING, (limit, limit))
libc = ctypes.CDLL(None, use_errno=True)
made = 0
for _ in range(20):
    tid = ctypes.c_void_p()
    made += libc.timer_create(1, None, ctypes.byref(tid)) == 0
print(made)
"""
#: Pending signals other processes of this uid may queue meanwhile (a loaded test machine).
SIGQ_SLACK = 300


def _uid_sigq() -> int:
    """Signals and timers queued by this uid across the host (this process's ``SigQ``, which
    counts every user namespace below it too)."""
    text = Path("/proc/self/status").read_text()
    return int(re.search(r"^SigQ:\s*(\d+)/", text, re.M).group(1))


def _bystander_timers(limit: int) -> int:
    """Timers (of 20) a process of this uid creates with RLIMIT_SIGPENDING ``limit``."""
    done = subprocess.run(
        [sys.executable, "-c", BYSTANDER_TIMERS, str(limit)],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    return int(done.stdout)


def test_queued_signals_and_timers_are_bounded_by_rlimit_sigpending() -> None:
    before = _uid_sigq()
    # A bystander whose limit leaves room for 20 timers over what the uid queues now, plus
    # what a bounded child and the machine's other processes may add: 20,000 would not fit.
    bystander_limit = before + MAX_PENDING_SIGNALS + SIGQ_SLACK + 20
    with host_intact(), held(SIGNALS, ["timers", "signals", "count"]) as child:
        timers = child.report()
        # POSIX timers are not refused: each is charged to RLIMIT_SIGPENDING, and the limit
        # ends them with EAGAIN.
        assert timers["limit"] == (MAX_PENDING_SIGNALS, MAX_PENDING_SIGNALS)
        assert 0 < timers["timers"] <= MAX_PENDING_SIGNALS, timers
        assert timers["errno"] == errno.EAGAIN
        assert _uid_sigq() - before <= MAX_PENDING_SIGNALS + SIGQ_SLACK
        assert _bystander_timers(bystander_limit) == 20
        child.go()
        child.report()  # 20,000 real-time signals queued to itself, with the timers gone
        assert _uid_sigq() - before <= MAX_PENDING_SIGNALS + SIGQ_SLACK
        assert _bystander_timers(bystander_limit) == 20
        child.go()
        counted = child.report()
    # Past the limit kill() still delivers the signal once, without its queue entry.
    assert 1 <= counted["queued"] <= MAX_PENDING_SIGNALS + 1, counted
    assert _uid_sigq() - before <= SIGQ_SLACK  # all given back


def test_without_the_limit_the_child_would_take_the_uids_timers() -> None:
    """The control: with the host's RLIMIT_SIGPENDING the child holds 20,000 timers, charged
    to the uid, and the bystander gets none of its 20."""
    before = _uid_sigq()
    with held(SIGNALS, ["timers"], disabled=("rlimits",), weak=True) as child:
        timers = child.report()
        assert "signals_bounded" in child.sandbox.weak
        assert timers["timers"] > 10 * MAX_PENDING_SIGNALS, timers
        assert _uid_sigq() - before > 10 * MAX_PENDING_SIGNALS
        assert _bystander_timers(before + MAX_PENDING_SIGNALS + SIGQ_SLACK + 20) < 20


# -- page cache, O_DIRECT, fadvise, madvise --------------------------------------------------

CACHE = """
import ctypes, fcntl, os
import numpy as np

PATH, (NR_MADVISE, NR_FCNTL, NR_OPENAT2) = {path!r}, {numbers!r}
libc = ctypes.CDLL(None, use_errno=True)
libc.mmap.restype = ctypes.c_void_p
libc.mmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int,
                      ctypes.c_int, ctypes.c_long)
libc.madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
libc.syscall.restype = ctypes.c_long
ADVICE = {{"remove": 9, "mergeable": 12, "cold": 20, "pageout": 21}}

def call(fn, *args):
    return 0 if fn(*args) != -1 else ctypes.get_errno()

def errno_of(fn, *args):
    try:
        fn(*args)
    except OSError as exc:
        return exc.errno
    return 0

def reward_function(params):
    out = {{}}
    fd = os.open(PATH, os.O_RDONLY)
    size = os.fstat(fd).st_size
    addr = libc.mmap(None, size, 1, 1, fd, 0)                 # PROT_READ, MAP_SHARED
    ctypes.string_at(addr, size)                              # every page mapped
    for name, advice in ADVICE.items():
        out[name] = call(libc.madvise, addr, size, advice)
    # The advice is an int: the kernel reads the low half of the register only.
    out["pageout_high_bits"] = call(libc.syscall, ctypes.c_long(NR_MADVISE),
                                    ctypes.c_void_p(addr), ctypes.c_size_t(size),
                                    ctypes.c_long((1 << 32) | 21))
    out["dontneed"] = call(libc.madvise, addr, size, 4)
    out["willneed"] = call(libc.madvise, addr, size, 3)
    libc.munmap(ctypes.c_void_p(addr), ctypes.c_size_t(size))
    out["o_direct"] = errno_of(os.open, PATH, os.O_RDONLY | os.O_DIRECT)
    out["setfl_direct"] = errno_of(fcntl.fcntl, fd, fcntl.F_SETFL, os.O_DIRECT)
    out["setfl_direct_high_bits"] = call(libc.syscall, ctypes.c_long(NR_FCNTL),
                                         ctypes.c_long(fd), ctypes.c_long((1 << 32) | 4),
                                         ctypes.c_long(os.O_DIRECT))
    out["setfl_nonblock"] = errno_of(fcntl.fcntl, fd, fcntl.F_SETFL, os.O_NONBLOCK)
    how = (ctypes.c_uint64 * 3)(os.O_RDONLY | os.O_DIRECT, 0, 0)
    out["openat2"] = call(libc.syscall, ctypes.c_long(NR_OPENAT2), ctypes.c_long(-100),
                          PATH.encode(), how, ctypes.c_size_t(24))
    big = np.ones(20_000_000)                                 # 160 MB: malloc's mmap/munmap
    out["numpy"] = float(big.sum())
    del big
    out["read"] = len(os.pread(fd, 4096, 0))
    # Last, with nothing of the file mapped: what would evict it for every process.
    out["fadvise_willneed"] = errno_of(os.posix_fadvise, fd, 0, 0, os.POSIX_FADV_WILLNEED)
    out["fadvise_dontneed"] = errno_of(os.posix_fadvise, fd, 0, 0, os.POSIX_FADV_DONTNEED)
    print(repr(out))
    return 1.0
"""


def _resident(path: Path) -> tuple[int, int]:
    """(pages of ``path`` in the page cache, pages of ``path``), by mincore on a mapping of
    it in this process (which reads, and so brings in, none of them)."""
    size = path.stat().st_size
    pages = (size + PAGE - 1) // PAGE
    fd = os.open(path, os.O_RDONLY)
    try:
        addr = _libc.mmap(None, size, 1, 1, fd, 0)
        assert addr not in (None, ctypes.c_void_p(-1).value), ctypes.get_errno()
        try:
            vec = (ctypes.c_ubyte * pages)()
            assert _libc.mincore(addr, size, vec) == 0, ctypes.get_errno()
        finally:
            _libc.munmap(addr, size)
    finally:
        os.close(fd)
    return sum(v & 1 for v in vec), pages


def _cached_file(folder: Path, size: int) -> Path:
    """A file of ``size`` bytes on disk and in the page cache, clean (written back: the kernel
    evicts no dirty page on advice)."""
    path = folder / "shared.bin"
    with open(path, "wb") as f:
        f.write(os.urandom(size))
        os.fsync(f.fileno())
    path.read_bytes()
    return path


@pytest.mark.skipif(os.uname().machine not in SYSCALL_NUMBERS, reason="syscall numbers")
def test_the_child_cannot_evict_the_hosts_page_cache_nor_read_past_it(tmp_path: Path) -> None:
    path = _cached_file(tmp_path, 8 << 20)
    resident, pages = _resident(path)
    if resident < pages:
        pytest.skip(f"the machine keeps only {resident}/{pages} pages of a file just read")
    source = CACHE.format(path=str(path), numbers=SYSCALL_NUMBERS[os.uname().machine])
    limits = SandboxLimits(per_call_seconds=20.0, cpu_seconds=60, read_paths=(str(tmp_path),))
    with host_intact(tmp_path):
        result = evaluate_reward(source, [{}], limits=limits, python_guards=False)
    assert [o.value for o in result.outcomes] == [1.0], result.outcomes
    out = ast.literal_eval(result.output.strip().splitlines()[-1])
    eperm = errno.EPERM
    assert out == {
        "fadvise_dontneed": eperm, "fadvise_willneed": eperm,
        "remove": eperm, "mergeable": eperm, "cold": eperm, "pageout": eperm,
        "pageout_high_bits": eperm, "dontneed": 0, "willneed": 0,
        "o_direct": eperm, "setfl_direct": eperm, "setfl_direct_high_bits": eperm,
        "setfl_nonblock": 0, "openat2": errno.ENOSYS, "numpy": 20_000_000.0, "read": 4096,
    }  # fmt: skip
    assert _resident(path) == (pages, pages)  # every page of it still cached for the host


@pytest.mark.skipif(os.uname().machine not in SYSCALL_NUMBERS, reason="syscall numbers")
def test_without_seccomp_the_child_would_evict_them(tmp_path: Path, monkeypatch) -> None:
    """The control: the same code with seccomp off empties the cache of the file."""
    monkeypatch.setenv(ALLOW_WEAK_ENV, "1")
    path = _cached_file(tmp_path, 8 << 20)
    source = CACHE.format(path=str(path), numbers=SYSCALL_NUMBERS[os.uname().machine])
    limits = SandboxLimits(per_call_seconds=20.0, cpu_seconds=60, read_paths=(str(tmp_path),))
    result = evaluate_reward(
        source, [{}], limits=limits, python_guards=False, disabled_layers=("seccomp",)
    )
    assert "no_host_watch" in result.weak
    resident, pages = _resident(path)
    assert resident < pages // 2, (resident, pages)


# -- the disk --------------------------------------------------------------------------------

READ_ALL = """
import os, time

def reward_function(params):
    fd = os.open({path!r}, os.O_RDONLY)
    start, total = time.monotonic(), 0
    while chunk := os.read(fd, 1 << 20):
        total += len(chunk)
    print(repr({{"bytes": total, "seconds": time.monotonic() - start}}))
    return 1.0
"""


@pytest.mark.slow
def test_a_cold_read_is_paced_by_the_io_cgroup(tmp_path: Path) -> None:
    """12 MB that are not in the page cache, at 4 MB/s: at least 3 s (a lower bound, which a
    loaded machine only lengthens)."""
    size, rate = 12 << 20, 4 << 20
    path = tmp_path / "cold.bin"
    with open(path, "wb") as f:
        f.write(os.urandom(size))
        f.flush()
        os.fsync(f.fileno())
        os.posix_fadvise(f.fileno(), 0, 0, os.POSIX_FADV_DONTNEED)
    resident, pages = _resident(path)
    if resident > pages // 10:
        pytest.skip(f"the file stayed in the page cache here ({resident}/{pages} pages)")
    limits = SandboxLimits(
        per_call_seconds=60.0, cpu_seconds=60, start_seconds=120.0,
        read_paths=(str(tmp_path),), disk_bytes_per_second=rate,
    )  # fmt: skip
    result = evaluate_reward(
        READ_ALL.format(path=str(path)), [{}], limits=limits, python_guards=False
    )
    if result.layers.get("cgroup_io") != "active":
        pytest.skip(f"no io cgroup here: {result.layers.get('cgroup_io')}")
    assert [o.value for o in result.outcomes] == [1.0], result.outcomes
    out = ast.literal_eval(result.output.strip().splitlines()[-1])
    assert out["bytes"] == size
    assert out["seconds"] >= 0.7 * size / rate, out


def test_the_io_cgroup_limits_every_disk_with_media() -> None:
    sleeper = subprocess.Popen(["sleep", "60"])
    io = IoCgroup(5 << 20, 300)
    try:
        reason = io.confine(sleeper.pid)
        if reason is not None:
            pytest.skip(reason)
        limits = io.limits()
        disks = [dev for dev, media in block_devices() if media]
        assert disks
        for dev in disks:
            if io.version == 2:
                assert f"rbps={5 << 20}" in limits[dev] and "riops=300" in limits[dev]
            else:
                assert limits[dev] == f"{5 << 20} 300"
        assert Path(f"/proc/{sleeper.pid}/cgroup").read_text().count(io.path.name) == 1
    finally:
        sleeper.kill()
        sleeper.wait()
        io.remove()
    assert io.path is None


def test_without_a_disk_the_io_cgroup_says_so(tmp_path: Path) -> None:
    io = IoCgroup(1 << 20, 100, sys_block=tmp_path)
    sleeper = subprocess.Popen(["sleep", "60"])
    try:
        reason = io.confine(sleeper.pid)
    finally:
        sleeper.kill()
        sleeper.wait()
        io.remove()
    assert reason is not None
    assert "no disk" in reason or "no io cgroup controller" in reason


# -- fail closed, and the filter itself ------------------------------------------------------

ALL_ACTIVE = {name: "active" for r in REQUIREMENTS for name in r.providers}


@pytest.mark.parametrize(
    ("gone", "missing"),
    [
        ((), set()),
        (("cgroup_io",), set()),  # seccomp's refusal of O_DIRECT stands in
        (("seccomp",), {"no_host_watch"}),
        (("seccomp", "cgroup_io"), {"no_host_watch", "io_bound"}),
        (("rlimits",), {"signals_bounded"}),
    ],
)
def test_each_shared_resource_fails_closed_without_its_layer(
    gone: tuple[str, ...], missing: set[str]
) -> None:
    layers = {**ALL_ACTIVE, **{name: "unavailable: not here" for name in gone}}
    assert {r.name for r in missing_requirements(layers)} == missing


@pytest.mark.parametrize(
    ("gone", "warned", "errors"),
    [("cgroup_io", ["cgroup_io"], []), ("seccomp", [], ["no inotify"])],
)
def test_manage_py_check_says_what_is_lost(
    gone: str, warned: list[str], errors: list[str], settings, monkeypatch
) -> None:
    """Without the io cgroup seccomp still bounds the disk: a warning. Without seccomp nothing
    else keeps inotify and the page cache: an error that says how to get it."""
    settings.RACECRAFT_ALLOW_WEAK_SANDBOX = False
    monkeypatch.delenv(ALLOW_WEAK_ENV, raising=False)
    monkeypatch.setenv(SIMULATE_ENV, gone)
    checks._layers.cache_clear()
    try:
        messages = checks.isolation_messages()
    finally:
        checks._layers.cache_clear()
    warnings = [m.msg for m in messages if m.id == "racecraft.W011"]
    assert [w.split("'")[1] for w in warnings] == warned
    found = [m for m in messages if m.level >= ERROR]
    assert len(found) == len(errors), [m.msg for m in found]
    for message, words in zip(found, errors, strict=True):
        assert words in message.msg and "libseccomp2" in message.hint


@pytest.mark.parametrize(
    ("arch", "o_direct"),
    [(seccomp.SCMP_ARCH_X86_64, 0o40000), (seccomp.SCMP_ARCH_AARCH64, 0o200000)],
    ids=["x86_64", "aarch64"],
)
def test_the_filter_refuses_them_on_each_architecture(arch: int, o_direct: int) -> None:
    text = seccomp.filter_text(arch=arch)
    for name in ("inotify_init1", "inotify_add_watch", "fanotify_init", "fadvise64"):
        assert re.search(rf'syscall "{name}" \(\d+\)', text), name
    madvise = text.split('syscall "madvise"')[1].split("# filter for")[0]
    for advice in seccomp.REFUSED_MADVISE.values():
        assert f"& 0xffffffff == {advice}" in madvise, advice
    assert "== 4\n" not in madvise  # MADV_DONTNEED stays allowed (malloc)
    openat = text.split('syscall "openat"')[1].split("# filter for")[0]
    assert f"& {o_direct:#010x} == {o_direct}" in openat
