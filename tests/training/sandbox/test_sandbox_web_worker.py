"""Validations on a real Celery worker, through the web: the Validate endpoint queues a task
that the worker runs in the sandbox and the browser polls; a slow validation does not hold up
other requests; deep sources are checked and run. One worker serves the module (the helpers
and the per-test reset of counts and queue are test_sandbox_web.py's)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

from tests.support import ChildProcess, celery_worker_process
from tests.training.sandbox.test_sandbox_web import (  # noqa: F401 - fixtures
    OK,
    RUNTIME,
    SLOW,
    _elif_table,
    _fresh_counts,
    start,
    wait_done,
)


@pytest.fixture
def alice_client(db) -> Client:
    client = Client()
    client.force_login(get_user_model().objects.create_user("alice", password="x-9-y-8-z"))
    return client


@pytest.fixture(scope="module")
def worker(
    redis_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ChildProcess]:
    """A worker on the quick queue for the module (it keeps nothing between validations)."""
    env = {**os.environ, **redis_env, "DJANGO_SETTINGS_MODULE": "console.settings"}
    with celery_worker_process(
        queues=["interactive"], env=env, log_path=tmp_path_factory.mktemp("worker") / "worker.log"
    ) as process:
        yield process


@pytest.mark.slow
def test_validation_runs_in_a_worker_and_is_polled(alice_client, worker) -> None:
    response = start(alice_client, OK)
    assert response.status_code == 202 and response.json()["status"] == "queued"
    body = wait_done(alice_client, response.json()["poll"])
    assert body["ok"] is True and body["rewards"]
    body = wait_done(alice_client, start(alice_client, RUNTIME).json()["poll"])
    assert body["ok"] is False and body["errors"][0]["type"] == "TEST_FAILURE"
    assert body["errors"][0]["lineNumber"] == 3


@pytest.mark.slow
def test_a_slow_validation_does_not_hold_up_other_requests(alice_client, worker) -> None:
    slow = start(alice_client, SLOW)
    assert slow.status_code == 202
    poll = slow.json()["poll"]
    # The slow one is still going (5 s per situation) while other requests are answered.
    assert alice_client.get(poll).json()["status"] in ("queued", "running")
    assert alice_client.get("/").status_code == 200
    assert alice_client.get(poll).json()["status"] in ("queued", "running")
    body = wait_done(alice_client, poll, seconds=300)
    assert "took longer than 5 s per call" in body["errors"][0]["message"]


@pytest.mark.slow
def test_deep_sources_through_the_web_and_a_worker(alice_client, worker) -> None:
    """Issue 22: a 500-branch elif table is checked (web, worker, sandbox) and runs; one nested
    past what can be checked, and the metaclass hole, are answered at once with their line."""
    response = start(alice_client, _elif_table(500))
    assert response.status_code == 202
    body = wait_done(alice_client, response.json()["poll"])
    assert body["ok"] is True and body["rewards"], body
    deeper = "def reward_function(params):\n    return (" + "lambda: " * 2000 + "1.0)\n"
    body = start(alice_client, deeper).json()
    assert body["status"] == "done" and body["ok"] is False
    (error,) = body["errors"]
    assert error["message"].startswith("the reward function is nested too deeply to check: ")
    assert error["lineNumber"] == 2
    hostile = Path(__file__).parent / "hostile" / "match_metaclass_getattr_no_dunder_literal.py"
    body = start(alice_client, hostile.read_text()).json()
    assert body["status"] == "done" and body["errors"][0]["lineNumber"] == 11
    assert "may not derive from 'type'" in body["errors"][0]["message"]
