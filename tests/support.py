"""Real servers for the integration tests, in one place: a Celery worker, daphne, a moto S3
server on loopback and Chromium.

tests/conftest.py registers this module as a pytest plugin, so its fixtures serve every test
package. Child processes run from the repository root on the tests' database, Redis (and key
prefix), store folder and tracks; each writes its output to a log file in the test's
``tmp_path``, and a process that dies or does not answer in time fails the test with that log.

A test marked ``browser`` is skipped, with the reason, before any of its fixtures start when
there is no Chromium at ``$RACECRAFT_TEST_CHROMIUM`` (default ``/usr/bin/chromium``).
"""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import tarfile
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from django.db import connection

ROOT = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 90.0
"""How long a child process may take to answer (worker ping, daphne port) before the test fails."""
STOP_TIMEOUT_S = 30.0
"""How long a child process may take to exit after SIGTERM before it is killed."""
DAPHNE_STOP_TIMEOUT_S = 5.0
"""daphne's: it exits only once the views already queued have run, one at a time in its sync
thread, and a closed Tracks page or wizard can leave dozens of track previews queued (each test
that opened one waited the whole 30 s for the kill). A test server has nothing to save."""

CHROMIUM_ENV = "RACECRAFT_TEST_CHROMIUM"
CHROMIUM_DEFAULT = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip

S3_ACCESS_KEY, S3_SECRET_KEY = "racecraft-test", "racecraft-test-secret"


OVAL_ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 2.0)]
"""Six discrete actions the end-to-end tests train with."""
CENTRE_LINE_REWARD = """
def reward_function(params):
    if not params["all_wheels_on_track"]:
        return 1e-3
    return 1.0 - params["distance_from_center"] / params["track_width"]
"""
"""A reward that pays for staying near the centre line (the end-to-end tests' reward)."""


def database_url() -> str:
    """The test database as a DATABASE_URL, so a child process uses the same one."""
    db = connection.settings_dict
    if db["ENGINE"].endswith("sqlite3"):
        return f"sqlite:///{db['NAME']}"
    user = db.get("USER") or ""
    auth = f"{user}@" if user else ""
    host, port = db.get("HOST") or "127.0.0.1", db.get("PORT") or 5432
    return f"postgres://{auth}{host}:{port}/{db['NAME']}"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def chromium_path() -> Path:
    """The Chromium the browser tests drive: ``$RACECRAFT_TEST_CHROMIUM`` or Debian's."""
    return Path(os.environ.get(CHROMIUM_ENV) or CHROMIUM_DEFAULT)


def _no_chromium_reason() -> str | None:
    path = chromium_path()
    if path.exists():
        return None
    return f"no Chromium at {path} (apt-get install -y chromium, or set {CHROMIUM_ENV})"


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skip a ``browser`` test before its fixtures start daphne or a worker for nothing."""
    if item.get_closest_marker("browser") and (reason := _no_chromium_reason()):
        pytest.skip(reason)


@dataclass(frozen=True)
class ChildProcess:
    """A running server or worker: its process, its log file and, for a server, its base URL."""

    popen: subprocess.Popen[bytes]
    log_path: Path
    url: str = ""

    def log(self) -> str:
        return self.log_path.read_text() if self.log_path.exists() else ""


def stop_child(popen: subprocess.Popen, timeout_s: float = STOP_TIMEOUT_S) -> None:
    """SIGTERM, then SIGKILL after ``timeout_s``; reaped either way."""
    popen.terminate()
    try:
        popen.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        popen.kill()
        popen.wait()


@contextmanager
def _running(
    command: Sequence[str],
    *,
    env: dict[str, str],
    log_path: Path,
    ready: Callable[[], bool],
    what: str,
    url: str = "",
    stop_timeout_s: float = STOP_TIMEOUT_S,
) -> Iterator[ChildProcess]:
    """Start ``command`` in the repository root, wait until ``ready()``, stop it on exit."""
    with open(log_path, "w") as log:
        popen = subprocess.Popen(
            list(command), cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT
        )
        child = ChildProcess(popen, log_path, url)
        try:
            deadline = time.monotonic() + START_TIMEOUT_S
            while not ready():
                if popen.poll() is not None:
                    pytest.fail(f"{what} exited with code {popen.returncode}\n{child.log()}")
                if time.monotonic() > deadline:
                    pytest.fail(f"{what} did not answer in {START_TIMEOUT_S:.0f} s\n{child.log()}")
                time.sleep(0.2)
            yield child
        finally:
            stop_child(popen, stop_timeout_s)


def celery_worker_process(
    *,
    queues: Sequence[str],
    env: dict[str, str],
    log_path: Path,
    concurrency: int = 1,
    pool: str | None = None,
) -> AbstractContextManager[ChildProcess]:
    """A real ``celery -A console worker`` on ``queues``, ready once it answers a ping."""
    from console.celery import app

    name = f"test-{uuid.uuid4().hex[:8]}"
    command = [sys.executable, "-m", "celery", "-A", "console", "worker",
               "-Q", ",".join(queues), "-c", str(concurrency), "-n", f"{name}@%h",
               "--without-gossip", "--without-mingle", "-l", "INFO"]  # fmt: skip
    if pool:
        command += ["--pool", pool]

    def answers() -> bool:
        replies = app.control.ping(timeout=1.0)
        return any(worker.startswith(f"{name}@") for reply in replies for worker in reply)

    return _running(command, env=env, log_path=log_path, ready=answers, what="the Celery worker")


def daphne_process(*, env: dict[str, str], log_path: Path) -> AbstractContextManager[ChildProcess]:
    """daphne serving ``console.asgi`` (HTTP and websockets) on a free loopback port."""
    port = free_port()
    command = [sys.executable, "-m", "daphne", "-b", "127.0.0.1", "-p", str(port),
               "console.asgi:application"]  # fmt: skip

    def listens() -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", port)) == 0

    return _running(
        command,
        env=env,
        log_path=log_path,
        ready=listens,
        what="daphne",
        url=f"http://127.0.0.1:{port}",
        stop_timeout_s=DAPHNE_STOP_TIMEOUT_S,
    )


@pytest.fixture
def store_dir(tmp_path: Path, settings) -> Path:
    """A fresh model store folder for this test, in settings.STORE_DIR."""
    settings.STORE_DIR = tmp_path / "store"
    return settings.STORE_DIR


@pytest.fixture
def child_env(store_dir: Path, redis_env: dict[str, str], settings) -> dict[str, str]:
    """The environment of a child process on the tests' database, Redis, store and tracks."""
    return {
        **os.environ,
        **redis_env,
        "DATABASE_URL": database_url(),
        "STORE_DIR": str(store_dir),
        "RACECRAFT_TRACKS_DIR": str(settings.RACECRAFT_TRACKS_DIR),
        "DJANGO_SETTINGS_MODULE": "console.settings",
    }


@pytest.fixture
def celery_worker(child_env: dict[str, str], tmp_path: Path) -> Iterator[ChildProcess]:
    """A real worker on the training, evaluation, interactive and default queues (one process
    at a time).

    Its log is ``tmp_path / "worker.log"``.
    """
    with celery_worker_process(
        queues=["training", "evaluation", "interactive", "default"],
        env=child_env,
        log_path=tmp_path / "worker.log",
    ) as worker:
        yield worker


@pytest.fixture
def daphne(child_env: dict[str, str], tmp_path: Path) -> Iterator[ChildProcess]:
    """daphne on a free loopback port, with DEBUG on so that it serves the static files.

    ``daphne.url`` is its base URL, without a slash; its log is ``tmp_path / "daphne.log"``.
    """
    env = {**child_env, "DEBUG": "1"}
    with daphne_process(env=env, log_path=tmp_path / "daphne.log") as server:
        yield server


@pytest.fixture
def browser(monkeypatch: pytest.MonkeyPatch) -> Iterator[object]:
    """Chromium through Playwright's sync API (a ``playwright.sync_api.Browser``)."""
    from playwright.sync_api import sync_playwright

    if reason := _no_chromium_reason():
        pytest.skip(reason)
    # Playwright's sync API keeps an event loop running in this thread; the ORM calls of the
    # test itself are still plain synchronous code.
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=str(chromium_path()), args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture(scope="module")
def s3_endpoint() -> Iterator[str]:
    """``host:port`` of a moto S3 server on loopback for this module.

    It accepts the keys ``S3_ACCESS_KEY`` / ``S3_SECRET_KEY``.
    """
    from moto.server import ThreadedMotoServer

    names = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY")
    saved = {name: os.environ.get(name) for name in names}
    os.environ.update(zip(names, (S3_ACCESS_KEY, S3_SECRET_KEY), strict=True))
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    try:
        yield f"{host}:{port}"
    finally:
        server.stop()
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def train_in_thread(job, user, *, iterations: int, within_s: float):
    """Run a queued training job in a thread of this process, as ``racecraft_train`` does, and
    stop it once it has ``iterations`` updates (a stop request: however loaded the machine,
    never the time limit), or after ``within_s`` seconds. Returns the job as it ended."""
    import threading

    from django.db import connections

    from training import services
    from training.models import TrainingJob
    from training.worker.training import run_training_job

    def body() -> None:
        try:
            run_training_job(job.pk, "test")
        finally:
            connections.close_all()

    thread = threading.Thread(target=body, daemon=True)
    thread.start()
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline and thread.is_alive():
        if TrainingJob.objects.get(pk=job.pk).iterations >= iterations:
            break
        time.sleep(0.5)
    services.job_stop(job=TrainingJob.objects.get(pk=job.pk), user=user)
    thread.join(timeout=300)
    assert not thread.is_alive(), "the training job did not stop"
    return TrainingJob.objects.get(pk=job.pk)


def tar_gz(
    entries: dict[str, bytes], extra: Callable[[tarfile.TarFile], None] | None = None
) -> bytes:
    """A tar.gz of ``entries`` (member name -> bytes) as an upload would bring it, names as
    given (hostile ones included); ``extra`` adds members of other kinds (links, devices)."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w:gz", compresslevel=1) as tar:
        for name, data in entries.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        if extra:
            extra(tar)
    return raw.getvalue()


def constant(steering: float, speed: float) -> list[dict]:
    """A discrete action space of two identical actions: whatever the network picks, the car
    drives this one (scripted cars for races, from real checkpoints)."""
    return [{"steering_angle": steering, "speed": speed}] * 2
