"""Real processes for the fault-injection tests: a Celery worker on the test database, and
waiting on conditions with generous deadlines (never on a loaded machine's timing)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.support import database_url, stop_child

ROOT = Path(__file__).resolve().parents[2]
SMALL = {"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32}


def wait_for(predicate: Callable[[], object], timeout: float, what: str,
             log_path: Path | None = None, every: float = 0.5):  # fmt: skip
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    extra = log_path.read_text()[-6000:] if log_path and log_path.exists() else ""
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}\n{extra}")


@contextmanager
def celery_worker(
    log_path: Path, env: Mapping[str, str], *, queues: str = "training,default",
    name: str | None = None, ping_app=None, app: str = "console",
) -> Iterator[subprocess.Popen]:  # fmt: skip
    """A real ``celery worker`` (prefork, one process) of ``app`` on the test database."""
    node = name or f"faults-{uuid.uuid4().hex[:8]}@%h"
    full_env = {**os.environ, "DATABASE_URL": database_url(),
                "DJANGO_SETTINGS_MODULE": "console.settings", **env}  # fmt: skip
    log = open(log_path, "a")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(
        [sys.executable, "-m", "celery", "-A", app, "worker", "-Q", queues, "-c", "1",
         "-n", node, "--without-gossip", "--without-mingle", "-l", "INFO"],
        cwd=ROOT, env=full_env, stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        if ping_app is None:
            from console.celery import app as ping_app
        wait_for(lambda: proc.poll() is not None or ping_app.control.ping(timeout=1.0), 90,
                 "the Celery worker to answer", log_path)  # fmt: skip
        assert proc.poll() is None, log_path.read_text()[-4000:]
        yield proc
    finally:
        stop_child(proc)
        log.close()
