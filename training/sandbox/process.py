"""Parent side: start a sandbox child, talk to it, watch it, and clean up after it.

The child is a fresh interpreter (never a fork of the caller, whose memory may hold secrets)
with an empty environment. Time is measured only on the parent's monotonic clock, so nothing
the child writes can extend it: every wait for a message has a deadline (the caller's, and
``deadline_seconds`` over the whole run), and a watchdog thread kills the child's process
group (SIGKILL) when the overall deadline passes or a call it sees start (the heartbeat in
shared memory says only *that* a call is under way) lasts longer than the per-call limit. A
child that forges or stops its heartbeat is still caught by the message deadlines. Signals
inside the child are not relied upon.

A call's clock leaves out the time the process running it waited for a CPU (the kernel's own
count, ``/proc/<pid>/schedstat``, read by the parent): on a machine busy with other jobs a
reward that needs a millisecond can wait seconds for its turn, and that is the host's load,
not the user's code. Sleeping and blocking still count. The wall clock still ends any call at
:data:`CALL_BACKSTOP` times the limit, so a child cannot stretch its own clock past that by
keeping the CPUs busy.
"""

from __future__ import annotations

import contextlib
import logging
import mmap
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from training.sandbox.cgroup import ChildCgroup, IoCgroup, MemoryCgroup, PidsCgroup
from training.sandbox.child import BOOT, HEARTBEAT_BYTES
from training.sandbox.errors import (
    RewardError,
    RewardFunctionError,
    SandboxCrashed,
    SandboxError,
    SandboxProtocolError,
    SandboxStartError,
    SandboxTimeout,
    SandboxUnavailable,
)
from training.sandbox.limits import SandboxLimits
from training.sandbox.lockdown import CHILD_ENV
from training.sandbox.protocol import FrameReader, ProtocolError, encode, write_with_deadline
from training.sandbox.requirements import (
    REQUIREMENT_NAMES,
    REQUIREMENTS,
    describe_missing,
    missing_requirements,
    simulated_missing,
    weak_sandbox_allowed,
)

log = logging.getLogger(__name__)

PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])
WATCHDOG_PERIOD_S = 0.02
#: Added to the per-call limit for a reply to arrive (encoding, a loaded machine).
CALL_SLACK_S = 2.0
#: A call ends at this many times the per-call limit on the wall clock, however long it
#: waited for a CPU (module docstring).
CALL_BACKSTOP = 10.0
#: Closing a sandbox: how long to wait for its processes to stop (a few microseconds), then
#: for the waiter to reap the killed sandboxed process and exit (:func:`kill_and_reap`).
STOP_TIMEOUT_S = 2.0
REAP_TIMEOUT_S = 10.0
#: Memory a child may use for its imports and set-up (our code, before lock-down), on top of
#: its limits' ``memory_bytes``; at lock-down the cgroup is tightened to what it then holds
#: plus ``memory_bytes``.
STARTUP_MEMORY_BYTES = 2 << 30

_SIGNAL_WORDS = {
    signal.SIGKILL: "was killed (SIGKILL): the CPU-time limit, or the system ran out of memory",
    signal.SIGXCPU: "used up its CPU-time limit",
    signal.SIGXFSZ: "tried to write a file",
    signal.SIGSEGV: "crashed (segmentation fault), e.g. from recursion that is too deep",
    signal.SIGSYS: "made a forbidden system call",
    signal.SIGABRT: "aborted",
    signal.SIGBUS: "crashed (bus error)",
}


def _state(reason: str | None) -> str:
    return "active" if reason is None else f"unavailable: {reason}"


def runqueue_wait_s(pid: int) -> float | None:
    """Seconds the task ``pid`` has spent runnable but waiting for a CPU since it started (the
    second field of ``/proc/<pid>/schedstat``); None where the kernel does not say."""
    try:
        with open(f"/proc/{pid}/schedstat", "rb") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


def call_overran(wall_s: float, waited_s: float, limit_s: float) -> bool:
    """Whether a call under way for ``wall_s`` seconds, ``waited_s`` of them waiting for a CPU,
    has passed ``limit_s``: the time it ran or slept, or the wall-clock backstop."""
    return wall_s - waited_s > limit_s or wall_s > limit_s * CALL_BACKSTOP


def calling_pid(pid: int) -> int:
    """The process that runs the calls of the sandbox child ``pid``: the child itself, or the
    process it forked into its new PID namespace (the child then only waits for it)."""
    children = _children_of(pid)
    return children[0] if len(children) == 1 else pid


def _state_of(pid: int) -> str:
    """The kernel's one-letter state of ``pid`` (R, S, T, Z, ...); "X" when it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rpartition(b")")[2].split()[0].decode()
    except (OSError, IndexError):
        return "X"


def _pid_depth(pid: int) -> int:
    """How many PID namespaces ``pid`` is in (the ``NSpid`` line of its status); 0 if gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("NSpid:"):
                    return len(line.split()) - 1
    except OSError:
        pass
    return 0


def _children_of(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(c) for c in f.read().split()]
    except OSError:
        return []


def kill_and_reap(proc: subprocess.Popen[bytes]) -> None:
    """SIGKILL the sandbox child ``proc`` and everything under it, and reap it, leaving no
    zombie anywhere.

    ``proc`` is either the waiter outside the PID namespace (its one child is the sandboxed
    process, PID 1 there) or, without a PID namespace, the sandboxed process itself. Killing
    the process group let the waiter die before it had reaped its child: that child then
    stayed a zombie of the host's PID 1, holding its queued signals, for as long as PID 1 does
    not reap (issue 52). So the group is stopped first (a group signal reaches a child being
    forked too, so nothing new escapes), the waiter's children in a deeper PID namespace are
    killed (the kernel then kills all of that namespace), and the waiter is let go on to reap
    and exit; only a waiter that does not within :data:`REAP_TIMEOUT_S` is killed outright.
    """
    pid = proc.pid
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pid, signal.SIGSTOP)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    while _state_of(pid) not in "TtZX" and time.monotonic() < deadline:
        time.sleep(0.001)
    children, depth = _children_of(pid), _pid_depth(pid)
    if children and depth and all(_pid_depth(c) > depth for c in children):
        for child in children:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(child, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGCONT)
        try:
            proc.wait(REAP_TIMEOUT_S)
            return
        except subprocess.TimeoutExpired:
            pass
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pid, signal.SIGKILL)
    with contextlib.suppress(ProcessLookupError):
        proc.kill()


@dataclass(frozen=True)
class SandboxMessage:
    """What :meth:`SandboxProcess.recv` returns: a ``message`` the target sent with
    ``ctx.send``, or the ``result`` the target returned (then the child has finished)."""

    kind: str
    value: Any
    output: str = ""


class SandboxProcess:
    """One sandboxed child running ``target`` (``"module:function"``) with the user's reward.

    ``start()`` returns the report of isolation layers; ``send``/``recv`` exchange messages;
    ``close()`` always leaves no process, thread or descriptor behind.
    ``python_guards=False`` and ``disabled_layers`` (names from the layer report) switch
    layers off; only tests use them, to show that the remaining layers hold. Errors are raised as
    :class:`RewardFunctionError` (the user's code failed) or :class:`SandboxCrashed` and its
    subclasses (the child died, hung or misbehaved), each with a message in plain words.
    """

    def __init__(
        self,
        *,
        target: str,
        reward_source: str,
        args: Any = None,
        limits: SandboxLimits | None = None,
        prepare: str | None = None,
        python_guards: bool = True,
        disabled_layers: tuple[str, ...] = (),
        allow_weak: bool | None = None,
        deadline_seconds: float | None = None,
    ) -> None:
        self.target = target
        self.deadline_seconds = deadline_seconds
        self._deadline: float | None = None
        self.allow_weak = weak_sandbox_allowed() if allow_weak is None else allow_weak
        #: Protections missing but accepted (``allow_weak``); empty on a fully isolated run.
        self.weak: tuple[str, ...] = ()
        self.disabled_layers = disabled_layers
        self.source = reward_source
        self.args = args
        self.limits = limits or SandboxLimits()
        self.prepare = prepare
        self.python_guards = python_guards
        self.layers: dict[str, str] = {}
        self.output = ""
        self._proc: subprocess.Popen[bytes] | None = None
        self._kill_reason: str | None = None
        self._overran = False  # killed for time: the error is a SandboxTimeout
        self._stop = threading.Event()
        self._kill_lock = threading.Lock()
        self._watchdog: threading.Thread | None = None
        self._finished = False
        self._oom = False
        self._cgroup = PidsCgroup(2)
        self._memory = MemoryCgroup(0)
        self._io = IoCgroup(self.limits.disk_bytes_per_second, self.limits.disk_ops_per_second)

    # -- life cycle --------------------------------------------------------------------------
    def start(self) -> dict[str, str]:
        """Start the child and wait until it is locked down with the module loaded; returns
        the layer report. Raises a :class:`SandboxError` subclass when it cannot start."""
        self.launch()
        return self.wait_started()

    def launch(self) -> None:
        """Start the child and hand it its job, without waiting: several children then load
        at once (:meth:`wait_started` waits for each)."""
        if self.deadline_seconds is not None:
            self._deadline = time.monotonic() + self.deadline_seconds
        hb_fd = os.memfd_create("racecraft-sandbox-heartbeat", os.MFD_CLOEXEC)
        os.ftruncate(hb_fd, HEARTBEAT_BYTES)
        self._hb_map = mmap.mmap(hb_fd, HEARTBEAT_BYTES)
        self._hb = memoryview(self._hb_map).cast("q")
        to_child_r, self._to_child = os.pipe2(os.O_CLOEXEC)
        self._from_child, from_child_w = os.pipe2(os.O_CLOEXEC)
        child_fds = (to_child_r, from_child_w, hb_fd)
        try:
            self._proc = subprocess.Popen(
                [
                    sys.executable,
                    "-E",
                    "-s",
                    "-B",
                    "-c",
                    BOOT,
                    str(to_child_r),
                    str(from_child_w),
                    str(hb_fd),
                    str(os.getpid()),
                    PACKAGE_ROOT,
                ],
                env=dict(CHILD_ENV),
                cwd="/",
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                pass_fds=child_fds,
                close_fds=True,
                start_new_session=True,
            )
        except OSError as exc:
            self._close_fds()
            raise SandboxStartError(f"the sandbox process could not be started: {exc}") from exc
        finally:
            for fd in child_fds:
                os.close(fd)
        # Threads count as pids: the waiter outside the PID namespace and the sandboxed
        # process's main thread, plus room when threads are allowed.
        self._cgroup = PidsCgroup(66 if self.limits.allow_threads else 2)
        cgroup_state = self._confine("cgroup_pids", self._cgroup)
        self._memory = MemoryCgroup(self.limits.memory_bytes + STARTUP_MEMORY_BYTES)
        memory_state = self._confine("cgroup_memory", self._memory)
        io_state = self._confine("cgroup_io", self._io)
        self._reader = FrameReader(self._from_child, self.limits.max_message_bytes)
        os.set_blocking(self._to_child, False)
        self._watchdog = threading.Thread(target=self._watch, name="sandbox-watchdog", daemon=True)
        self._watchdog.start()
        job = {
            "target": self.target, "prepare": self.prepare, "args": self.args,
            "limits": self.limits.to_dict(), "source": self.source,
            "python_guards": self.python_guards, "disabled_layers": list(self.disabled_layers),
            "cgroup_pids": cgroup_state, "cgroup_memory": memory_state, "cgroup_io": io_state,
            "allow_weak": self.allow_weak,
            "simulate_missing": list(simulated_missing()),
        }  # fmt: skip
        try:
            self._write(job, self.limits.start_seconds)
        except BaseException:
            self.close()
            raise

    def _confine(self, layer: str, cgroup: ChildCgroup) -> str:
        assert self._proc is not None
        if layer in self.disabled_layers:
            return "disabled (test only)"
        return _state(cgroup.confine(self._proc.pid))

    def wait_started(self) -> dict[str, str]:
        """After :meth:`launch`: wait for the lock-down report and the loaded module."""
        try:
            self._locked(self._next(self.limits.start_seconds, "starting"))
            msg = self._next(
                self.limits.per_call_seconds + CALL_SLACK_S,
                "loading the module",
                late=self.late_words("loading the module"),
            )
        except BaseException:
            self.close()
            raise
        if msg.get("kind") != "ready":
            self.close()
            raise SandboxProtocolError("the sandbox did not start as expected")
        return self.layers

    def _locked(self, msg: dict[str, Any]) -> None:
        """Take the child's layer report, sent after lock-down and before any user code; refuse
        (fail closed) when a protection is missing, unless weak isolation was accepted."""
        kind = msg.get("kind")
        layers = msg.get("layers")
        if kind not in ("locked", "refused") or not isinstance(layers, dict):
            raise SandboxProtocolError("the sandbox did not start as expected")
        self.layers = {str(k): str(v)[:300] for k, v in layers.items()}
        missing = missing_requirements(self.layers)
        if kind == "refused":  # the child's own names, kept only when they are ours
            named = msg.get("missing")
            names = set(named) & REQUIREMENT_NAMES if isinstance(named, list) else set()
            missing = [r for r in REQUIREMENTS if r.name in names] or missing
            missing = missing or list(REQUIREMENTS)  # a refusal we cannot read: trust nothing
        if kind == "locked" and self.layers.get("cgroup_memory") == "active":
            # The kernel's limit: what the child holds now (its imports) plus its allowance.
            tightened = self._memory.tighten(self.limits.memory_bytes)
            if tightened is not None:
                self.layers["cgroup_memory"] = _state(tightened)
                missing = missing_requirements(self.layers)
        names = tuple(r.name for r in missing)
        if missing and (kind == "refused" or not self.allow_weak):
            raise SandboxUnavailable(describe_missing(missing), names)
        if missing:
            self.weak = names
            log.info("reward sandbox runs with weakened isolation: missing %s", names)
        try:
            self._write({"kind": "go"}, self.limits.start_seconds)
        except OSError:
            self._raise_dead("starting")

    def close(self, grace_seconds: float = 0.0) -> None:
        """Stop the child (after ``grace_seconds`` for a clean exit), reap it, stop the
        watchdog, close descriptors. Safe to call more than once."""
        proc = self._proc
        if proc is not None and proc.poll() is None:
            with contextlib.suppress(OSError):
                os.close(self._to_child)
                self._to_child = -1
            try:
                proc.wait(timeout=grace_seconds) if grace_seconds > 0 else None
            except subprocess.TimeoutExpired:
                pass
            self._kill(None)
        if proc is not None:
            proc.wait()
            self._oom = self._oom or self._memory.oom_killed()
            self._cgroup.remove()
            self._memory.remove()
            self._io.remove()
        self._stop.set()
        if self._watchdog is not None and self._watchdog is not threading.current_thread():
            self._watchdog.join()
        self._close_fds()

    def __enter__(self) -> SandboxProcess:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc else None

    # -- messages ----------------------------------------------------------------------------
    def send(self, value: Any) -> None:
        """Send ``value`` to the target's ``ctx.recv()``; a child that does not take it within
        the per-call limit (plus slack) is killed (:class:`SandboxTimeout`)."""
        try:
            self._write({"value": value}, self.limits.per_call_seconds + CALL_SLACK_S)
        except OSError:
            self._raise_dead("receiving a message")

    def late_words(self, what: str) -> str:
        """The user's words for a call that overran: "<what> took longer than N s per call"."""
        return f"{what} took longer than {self.limits.per_call_seconds:g} s per call"

    def fileno(self) -> int:
        """The pipe the child's messages come through (for ``select``; :meth:`ready` first,
        since a message may already be read into the buffer)."""
        return self._from_child

    def ready(self) -> bool:
        """Whether :meth:`recv` would answer at once (a message, or the child's end)."""
        return self._finished or self._reader.ready()

    def recv(self, timeout: float | None = None, *, late: str | None = None) -> SandboxMessage:
        """Next message from the child; raises on errors, death or ``timeout`` seconds (then
        the child is killed and ``late``, if given, is the reason the user reads)."""
        if self._finished:
            raise SandboxError("the sandboxed target has already finished")
        msg = self._next(timeout, "running", late=late)
        kind = msg.get("kind")
        if kind == "message":
            return SandboxMessage("message", msg.get("value"))
        if kind == "result":
            self._finished = True
            self.output = str(msg.get("output", ""))
            return SandboxMessage("result", msg.get("value"), self.output)
        self._kill("it sent malformed data (a message of an unknown kind)")
        raise SandboxProtocolError(self._describe_death())

    # -- internals ---------------------------------------------------------------------------
    def _write(self, obj: Any, timeout: float) -> None:
        """Write one message within ``timeout`` seconds (and the overall deadline): a child
        that stops reading (a full pipe it never drains) is killed, never waited for."""
        deadline = time.monotonic() + timeout
        if self._deadline is not None:
            deadline = min(deadline, self._deadline)
        try:
            write_with_deadline(self._to_child, encode(obj), deadline)
        except TimeoutError:
            self._overran = True
            self._kill(f"it stopped reading what it was sent for {timeout:g} s")
            raise SandboxTimeout(self._describe_death()) from None

    def _overall(self) -> str:
        return f"it ran past its overall limit of {self.deadline_seconds:g} s"

    def _next(
        self, timeout: float | None, doing: str, *, late: str | None = None
    ) -> dict[str, Any]:
        wait = timeout
        overall = False
        if self._deadline is not None:
            left = max(0.0, self._deadline - time.monotonic())
            overall = wait is None or left < wait
            wait = left if overall else wait
        try:
            msg = self._reader.read(wait)
        except TimeoutError:
            self._overran = True
            if overall:
                self._kill(self._overall())
            else:
                self._kill(late or f"it gave no answer within {timeout:g} s while {doing}")
            raise SandboxTimeout(self._describe_death()) from None
        except EOFError:
            self._raise_dead(doing)
        except ProtocolError as exc:
            self._kill(f"it sent malformed data ({exc})")
            raise SandboxProtocolError(self._describe_death()) from None
        if not isinstance(msg, dict):
            self._kill("it sent malformed data")
            raise SandboxProtocolError(self._describe_death())
        kind = msg.get("kind")
        if kind == "error":
            self.output = str(msg.get("output", ""))
            err = RewardError.from_dict(
                msg.get("error") if isinstance(msg.get("error"), dict) else {}
            )
            step = msg.get("step")
            self._finished = True
            raise RewardFunctionError(err, step if type(step) is int else None)
        if kind == "failure":
            self._finished = True
            raise SandboxCrashed(f"the sandbox failed: {str(msg.get('message'))[:500]}")
        return msg

    def _raise_dead(self, doing: str) -> None:
        assert self._proc is not None
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._kill("it closed its channel but did not exit")
        err = SandboxTimeout if self._overran else SandboxCrashed
        raise err(self._describe_death())

    def _describe_death(self) -> str:
        proc = self._proc
        code = proc.wait() if proc is not None else None
        self._oom = self._oom or self._memory.oom_killed()
        if self._kill_reason:
            why = self._kill_reason
        elif self._oom:
            mb = self.limits.memory_bytes / (1 << 20)
            why = f"it used more than its memory limit ({mb:,.0f} MB beyond its start-up)"
        elif code is not None and code < 0:
            sig = signal.Signals(-code)
            why = _SIGNAL_WORDS.get(sig, f"was stopped by signal {sig.name}")
        else:
            why = f"exited unexpectedly (status {code})"
        return f"The reward function's sandbox was stopped: {why}."

    def _kill(self, reason: str | None) -> None:
        if reason and not self._kill_reason:
            self._kill_reason = reason
        proc = self._proc
        if proc is None or proc.returncode is not None:
            return
        with self._kill_lock:
            kill_and_reap(proc)

    def _watch(self) -> None:
        """Kill the child past the overall deadline, or when a call has been under way for
        longer than the per-call limit: durations on our clock, from when we first saw the
        heartbeat change (its contents are the child's, so they only mark a call's start)."""
        limit = self.limits.per_call_seconds
        proc = self._proc
        assert proc is not None
        seen, since = (0, 0), time.monotonic()
        waited: float | None = None  # the kernel's count when this call's own clock began
        unseen = 0.0  # the part of the call before that, when this thread itself was late
        caller: int | None = None
        while not self._stop.wait(WATCHDOG_PERIOD_S):
            if proc.poll() is not None:
                return
            now = time.monotonic()
            if self._deadline is not None and now > self._deadline:
                self._overran = True
                self._kill(self._overall())
                return
            mark = (self._hb[0], self._hb[1])
            # A call starts when the step moves on or the start stamp goes from 0 to set; a
            # stamp refreshed within one call does not restart its clock.
            if mark[0] != seen[0] or (mark[1] and not seen[1]):
                since, waited = now, None
            elif mark[1] and waited is None:
                # The same call a tick later (most take microseconds): from here on its
                # process's wait for a CPU is left out of its clock; the kernel is asked
                # only for calls this long, never in a run of quick ones. A tick is
                # charged for the time before; more than that is this thread running late.
                caller = caller or calling_pid(proc.pid)  # calls begin after any fork
                waited = runqueue_wait_s(caller)
                unseen = max(0.0, now - since - WATCHDOG_PERIOD_S)
            seen = mark
            if (
                mark[1]
                and now - since > limit
                and self._overran_call(now - since, caller, waited, unseen)
            ):
                step = mark[0]
                what = f"reward_function at step {step}" if step else "loading the module"
                self._overran = True
                self._kill(self.late_words(what))
                return

    def _overran_call(
        self, wall_s: float, caller: int | None, waited: float | None, unseen: float
    ) -> bool:
        """A call under way for ``wall_s`` (past the limit on the wall clock): whether it passed
        the limit once the time its process waited for a CPU since ``waited`` (the kernel's
        count then), and ``unseen`` before that, are left out."""
        queued = 0.0
        if caller is not None and waited is not None:
            now_waited = runqueue_wait_s(caller)
            queued = 0.0 if now_waited is None else unseen + max(0.0, now_waited - waited)
        return call_overran(wall_s, queued, self.limits.per_call_seconds)

    def _close_fds(self) -> None:
        for name in ("_to_child", "_from_child"):
            fd = getattr(self, name, -1)
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
                setattr(self, name, -1)
        hb = getattr(self, "_hb", None)
        if hb is not None:
            hb.release()
            self._hb = None
            self._hb_map.close()
