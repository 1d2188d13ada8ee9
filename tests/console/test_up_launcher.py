"""The process supervisor, the embedded Redis and `manage.py up` end to end."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest
import redis
from celery import Celery

from console.launcher import ChildSpec, EmbeddedRedis, LaunchError, Supervisor
from console.redisconf import celery_url

REPO = Path(__file__).resolve().parents[2]


def _sleeper(name: str) -> ChildSpec:
    return ChildSpec(name=name, argv=[sys.executable, "-c", "import time; time.sleep(120)"])


def _gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def test_a_dying_child_stops_the_others() -> None:
    with Supervisor(stop_timeout=5) as sup:
        first = sup.start(_sleeper("first"))
        second = sup.start(_sleeper("second"))
        sup.start(ChildSpec(name="crasher", argv=[sys.executable, "-c", "raise SystemExit(3)"]))
        assert sup.run() == 1
    assert sup.failure == "crasher exited with code 3"
    assert first.process.returncode is not None
    assert second.process.returncode is not None
    assert sup.children == []


def test_request_stop_ends_run_cleanly() -> None:
    with Supervisor(stop_timeout=5) as sup:
        child = sup.start(_sleeper("sleeper"))
        threading.Timer(0.5, sup.request_stop).start()
        assert sup.run() == 0
    assert sup.failure is None
    assert child.process.returncode == -signal.SIGTERM


def test_a_child_ignoring_sigterm_is_killed() -> None:
    stubborn = ChildSpec(
        name="stubborn",
        argv=[sys.executable, "-c",
              "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN);"
              "print('ready', flush=True); time.sleep(120)"],
    )  # fmt: skip
    sup = Supervisor(stop_timeout=0.5)
    child = sup.start(stubborn)
    time.sleep(1.0)  # let it install its handler
    sup.stop_all()
    assert child.process.returncode == -signal.SIGKILL


def test_a_missing_program_is_a_launch_error() -> None:
    with Supervisor() as sup, pytest.raises(LaunchError, match="could not start ghost"):
        sup.start(ChildSpec(name="ghost", argv=["/nonexistent/racecraft-ghost"]))


def test_wait_until_reports_a_child_that_died() -> None:
    with Supervisor() as sup:
        sup.start(ChildSpec(name="quitter", argv=[sys.executable, "-c", "pass"]))
        with pytest.raises(LaunchError, match="quitter exited with code 0"):
            sup.wait_until(lambda: False, what="nothing", timeout=30)


@pytest.fixture
def short_dir() -> Iterator[Path]:
    """A folder with a short path: unix socket paths are limited to ~107 bytes."""
    with tempfile.TemporaryDirectory(prefix="rc-") as name:
        yield Path(name)


def test_embedded_redis_serves_redis_py_and_celery_urls(short_dir: Path) -> None:
    embedded = EmbeddedRedis(short_dir / "redis" / "redis.sock")
    assert not embedded.ping()
    with Supervisor(stop_timeout=5) as sup:
        sup.start(embedded.spec())
        sup.wait_until(embedded.ping, what="redis", timeout=30)
        client = redis.Redis.from_url(embedded.url.replace("db=0", "db=2"))
        client.set("k", "v")
        assert client.get("k") == b"v"
        client.close()
        # Celery's spelling of the same socket reaches the same database.
        app = Celery(
            "probe", broker=celery_url(embedded.url.replace("db=0", "db=2")), set_as_current=False
        )
        with app.connection_for_write() as conn:
            assert conn.default_channel.client.get("k") == b"v"
        with pytest.raises(LaunchError, match="already answers"):
            EmbeddedRedis(embedded.socket_path).spec()
    assert not embedded.socket_path.exists() or not embedded.ping()


def test_embedded_redis_falls_back_to_a_short_socket_path(tmp_path: Path) -> None:
    embedded = EmbeddedRedis(tmp_path / ("x" * 120) / "redis.sock")
    assert len(str(embedded.socket_path)) <= 100
    assert embedded.url == f"unix://{embedded.socket_path}?db=0"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _up_env(var_dir: Path, db_file: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("REDIS_URL", "REDIS_PREFIX")}
    env |= {"DATABASE_URL": f"sqlite:///{db_file}", "RACECRAFT_VAR_DIR": str(var_dir)}
    return env


def _wait_for_http(url: str, proc: subprocess.Popen[bytes], timeout: float) -> bytes:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"manage.py up exited with {proc.returncode}"
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                return response.read()
        except OSError:
            time.sleep(0.3)
    raise AssertionError(f"{url} did not answer in {timeout} s")


@pytest.mark.slow
def test_manage_py_up_serves_runs_tasks_and_stops_on_sigterm(short_dir: Path) -> None:
    port = _free_port()
    var_dir = short_dir / "var"
    up = subprocess.Popen(
        [sys.executable, "manage.py", "up", "--port", str(port), "--concurrency", "1"],
        cwd=REPO,
        env=_up_env(var_dir, short_dir / "db.sqlite3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    output = b""
    try:
        home = _wait_for_http(f"http://127.0.0.1:{port}/", up, timeout=120)
        assert b"Racecraft" in home
        css = _wait_for_http(f"http://127.0.0.1:{port}/static/css/app.css", up, timeout=10)
        assert b"--accent" in css

        # The worker answers a ping through the embedded Redis under var/.
        socket_path = var_dir / "redis" / "redis.sock"
        assert socket_path.exists()
        # Not the current app: shared tasks elsewhere in the session must keep the real one.
        probe = Celery(
            "probe", broker=celery_url(f"unix://{socket_path}?db=0"), set_as_current=False
        )
        probe.conf.result_backend = probe.conf.broker_url
        result = probe.send_task("console.tasks.ping", args=["from-test"], queue="default")
        assert result.get(timeout=120) == "from-test"

        children = psutil.Process(up.pid).children(recursive=True)
        names = " ".join(" ".join(child.cmdline()) for child in children)
        assert "daphne" in names
        assert "celery" in names
        assert "redis-server" in names

        up.send_signal(signal.SIGTERM)
        output, _ = up.communicate(timeout=60)
        assert up.returncode == 0, output.decode(errors="replace")
    finally:
        if up.poll() is None:
            up.kill()
            output, _ = up.communicate()
    text = output.decode(errors="replace")
    assert f"Racecraft is running at http://127.0.0.1:{port}" in text
    assert "racecraft: stopped" in text
    if "DEBUG" not in os.environ and "SECRET_KEY" not in os.environ:
        # Nothing configured (the README's one command): debug mode on loopback, said so, with
        # a key of this install's own, never the public development key.
        assert "racecraft: debug mode (DEBUG unset or 1): this machine only" in text
        assert len((var_dir / "secret_key").read_text().strip()) >= 50
    deadline = time.monotonic() + 15
    while not all(_gone(child.pid) for child in children) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert [c.pid for c in children if not _gone(c.pid)] == []


@pytest.mark.slow
def test_manage_py_up_refuses_a_busy_port(short_dir: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = subprocess.run(
            [sys.executable, "manage.py", "up", "--port", str(port)],
            cwd=REPO,
            env=_up_env(short_dir / "var", short_dir / "db.sqlite3"),
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert result.returncode != 0
    assert f"port {port} on 127.0.0.1 is already in use" in result.stderr


@pytest.mark.slow
def test_manage_py_up_stops_everything_when_the_worker_dies(short_dir: Path) -> None:
    port = _free_port()
    up = subprocess.Popen(
        [sys.executable, "manage.py", "up", "--port", str(port), "--concurrency", "1"],
        cwd=REPO,
        env=_up_env(short_dir / "var", short_dir / "db.sqlite3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        _wait_for_http(f"http://127.0.0.1:{port}/", up, timeout=120)
        children = psutil.Process(up.pid).children(recursive=True)
        worker = next(c for c in psutil.Process(up.pid).children() if "celery" in c.cmdline())
        worker.kill()
        output, _ = up.communicate(timeout=60)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    text = output.decode(errors="replace")
    assert up.returncode == 1, text
    names = ("worker-quick", "worker-training", "worker-evaluation", "beat")
    name = next(w for w in names if f"{w} was killed" in text)
    assert f"{name} was killed by SIGKILL; stopping the other processes" in text
    assert f"racecraft stopped: {name} was killed by SIGKILL" in text
    deadline = time.monotonic() + 15
    while not all(_gone(child.pid) for child in children) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert [c.pid for c in children if not _gone(c.pid)] == []
