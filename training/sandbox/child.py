"""Entry point of a sandbox child process (``python -E -s -B -c BOOT ...``).

Sequence: clean environment, close inherited fds, read the job, new namespaces (while
single-threaded; a fork makes the rest PID 1 of a new PID namespace), import the allowed
libraries and the target, run the target's ``prepare``, apply rlimits, a root of its own
(only the read paths and its own /proc exist: :mod:`training.sandbox.rootfs`), no_new_privs,
Landlock and seccomp, check that every protection the user code must not escape is in force
(:mod:`training.sandbox.requirements`; else refuse, fail closed), report the layers, wait for
the parent's go (it tightens the memory cgroup first), then load the user's module and run the
target with the guarded reward callable. Nothing here trusts the user code: after it has run,
the parent treats everything this process says as untrusted.
"""

from __future__ import annotations

import ctypes
import importlib
import mmap
import os
import signal
import time
from collections.abc import Callable
from typing import Any

from training.sandbox import landlock, lockdown, seccomp, taint
from training.sandbox.errors import RewardFunctionError
from training.sandbox.guard import RewardCallable, install_output_capture, load_reward_function
from training.sandbox.limits import SandboxLimits
from training.sandbox.protocol import read_message_blocking, write_message
from training.sandbox.requirements import apply_simulation, missing_requirements

PR_SET_PDEATHSIG = 1
HEARTBEAT_BYTES = 4096
#: Imported before lock-down so that user imports are served from memory.
PREIMPORTS = ("math", "random", "numpy", "scipy", "shapely", "shapely.geometry", "scipy.spatial")
#: Also imported when Landlock is missing (then every open() is refused after lock-down).
PREIMPORTS_NO_LANDLOCK = (
    "scipy.interpolate",
    "scipy.optimize",
    "scipy.signal",
    "scipy.stats",
    "scipy.special",
    "scipy.linalg",
    "shapely.ops",
    "shapely.affinity",
)


def resolve(dotted: str) -> Callable[..., Any]:
    """``"package.module:function"`` -> the function."""
    module_name, _, attr = dotted.partition(":")
    obj: Any = importlib.import_module(module_name)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


class SandboxContext:
    """What a target function receives: ``reward`` (the guarded callable), ``args``,
    ``prepared`` (what the prepare hook returned), ``layers``, and a channel to the parent."""

    def __init__(
        self,
        *,
        reward: RewardCallable,
        args: Any,
        prepared: Any,
        layers: dict[str, str],
        ctl_in: int,
        out: int,
        output: Any,
        source: str = "",
        python_guards: bool = True,
    ) -> None:
        self.reward = reward
        self._source = source
        self._guards = python_guards
        self.args = args
        self.prepared = prepared
        self.layers = layers
        self._in = ctl_in
        self._out = out
        self._output = output

    def send(self, value: Any) -> None:
        """Send a message the parent receives with ``SandboxProcess.recv``."""
        write_message(self._out, {"kind": "message", "value": value})

    def recv(self) -> Any:
        """Next value from the parent's ``send``; None when the parent closed the channel."""
        try:
            msg = read_message_blocking(self._in)
        except EOFError:
            return None
        return msg.get("value")

    def take_output(self) -> str:
        """The user's captured ``print`` output since the last call."""
        return self._output.take()

    def new_reward(self) -> RewardCallable:
        """Another, independent instance of the user's module (its own module-level state),
        guarded like ``reward``: one per simulated car, as DeepRacer runs one car per process.
        Raises RewardFunctionError if the module fails to load."""
        hb = self.reward._hb
        hb[1] = time.monotonic_ns()
        try:
            fn = load_reward_function(self._source, python_guards=self._guards)
        finally:
            hb[1] = 0
        return RewardCallable(fn, hb)


def _die_with_parent(parent_pid: int | None) -> None:
    """SIGKILL when the parent goes; ``parent_pid`` None after the fork into the PID
    namespace, where the parent (outside it) has no pid to compare."""
    ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(1)


def main(argv: list[str]) -> None:
    out = int(argv[1])
    try:
        _main(argv)
    except BaseException as exc:  # noqa: BLE001 - a failure before the user code ran
        try:
            write_message(out, {"kind": "failure", "message": f"{type(exc).__name__}: {exc}"})
        finally:
            os._exit(3)


def _main(argv: list[str]) -> None:
    ctl_in, out, hb_fd, parent_pid = (int(a) for a in argv)
    _die_with_parent(parent_pid)
    caller_uid = os.getuid()  # before the user namespace maps it to "nobody"
    layers = {"environment": lockdown.ACTIVE}
    lockdown.clean_environment()
    lockdown.close_inherited_fds({ctl_in, out, hb_fd})
    layers["file_descriptors"] = lockdown.ACTIVE
    job = read_message_blocking(ctl_in)
    skip = frozenset(job.get("disabled_layers") or ())
    others, mount = "namespaces" not in skip, "mount_namespace" not in skip
    # From here on, PID 1 of a new PID namespace (with ``others``); the mount namespace's
    # root is built at lock-down (``mount_namespace`` in the report).
    ns = lockdown.unshare_namespaces(others=others, mount=mount) if others or mount else None
    if not others:
        layers["namespaces"] = "disabled (test only)"
    else:
        layers["namespaces"] = lockdown.ACTIVE if ns is None else f"unavailable: {ns}"
        if ns is None:
            _die_with_parent(None)
    limits = SandboxLimits.from_dict(job["limits"])
    hb_map = mmap.mmap(hb_fd, HEARTBEAT_BYTES)
    os.close(hb_fd)
    heartbeat = memoryview(hb_map).cast("q")
    has_landlock = landlock.abi_version() > 0 and "landlock" not in skip
    for name in PREIMPORTS + (() if has_landlock else PREIMPORTS_NO_LANDLOCK):
        importlib.import_module(name)
    seccomp.library()  # loaded while its file can still be read
    target = resolve(job["target"])
    prepared = resolve(job["prepare"])(job["args"]) if job.get("prepare") else None
    layers.update(
        lockdown.apply_all(
            cpu_seconds=limits.cpu_seconds,
            memory_bytes=limits.memory_bytes,
            open_files=limits.open_files,
            allow_threads=limits.allow_threads,
            read_paths=limits.read_paths,
            caller_uid=caller_uid,
            skip=skip,
        )
    )
    guards = bool(job.get("python_guards", True))
    layers["python_guards"] = lockdown.ACTIVE if guards else "disabled (test only)"
    layers["cgroup_pids"] = str(job.get("cgroup_pids", "unavailable: not reported"))
    layers["cgroup_memory"] = str(job.get("cgroup_memory", "unavailable: not reported"))
    layers["cgroup_io"] = str(job.get("cgroup_io", "unavailable: not reported"))
    apply_simulation(layers, tuple(job.get("simulate_missing") or ()))
    # Fail closed: nothing of the user's is loaded unless every protection is in force.
    missing = [r.name for r in missing_requirements(layers)]
    if missing and not job.get("allow_weak"):
        write_message(out, {"kind": "refused", "missing": missing, "layers": layers})
        os._exit(0)
    write_message(out, {"kind": "locked", "layers": layers})
    # The parent sets the kernel's memory limit to what we hold now plus our allowance, then
    # says go: nothing of the user's runs before that.
    go = read_message_blocking(ctl_in)
    if not isinstance(go, dict) or go.get("kind") != "go":
        os._exit(0)
    output = install_output_capture(limits.max_output_chars)
    taint.mark()  # from here on, nothing in this process judges a lap for anyone
    heartbeat[0] = 0
    heartbeat[1] = time.monotonic_ns()
    try:
        fn = load_reward_function(job["source"], python_guards=guards)
    except RewardFunctionError as exc:
        heartbeat[1] = 0
        write_message(
            out,
            {"kind": "error", "error": exc.error.to_dict(), "step": None, "output": output.take()},
        )
        os._exit(0)
    heartbeat[1] = 0
    reward = RewardCallable(fn, heartbeat)
    write_message(out, {"kind": "ready", "layers": layers})
    ctx = SandboxContext(
        reward=reward,
        args=job["args"],
        prepared=prepared,
        layers=layers,
        ctl_in=ctl_in,
        out=out,
        output=output,
        source=job["source"],
        python_guards=guards,
    )
    try:
        value = target(ctx)
        reply = {"kind": "result", "value": value, "output": output.take()}
    except RewardFunctionError as exc:
        reply = {
            "kind": "error",
            "error": exc.error.to_dict(),
            "step": exc.step,
            "output": output.take(),
        }
    except BaseException as exc:  # noqa: BLE001 - report, then exit
        reply = {"kind": "failure", "message": f"{type(exc).__name__}: {str(exc)[:500]}"}
    try:
        write_message(out, reply)
    finally:
        os._exit(0)


#: Run by the child interpreter; argv: ctl_in out heartbeat parent_pid package_root.
BOOT = (
    "import sys; sys.path[:] = [p for p in sys.path if p]; sys.path.insert(0, sys.argv[5]); "
    "from training.sandbox.child import main; main(sys.argv[1:5])"
)
