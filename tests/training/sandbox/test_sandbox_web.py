"""The web process runs no reward code: the Validate endpoint queues a Celery task and the
browser polls it; per-user limits; a slow validation does not hold up other requests."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import redis
from django.conf import settings as django_settings
from django.contrib.auth import get_user_model
from django.test import Client

from console.celery import app as celery_app
from tests.support import ChildProcess, celery_worker_process

URL = "/api/reward/validate"
OK = "def reward_function(params):\n    return float(params['progress']) / 100 + 1e-3\n"
SLOW = "def reward_function(params):\n    while True:\n        pass\n"
RUNTIME = "def reward_function(params):\n\n    return params['no_such_key']\n"


@pytest.fixture(autouse=True)
def _fresh_counts() -> None:
    """User ids repeat across tests (the database rolls back, Redis does not): start each
    test with no counts and no queued validations."""
    client = redis.Redis.from_url(django_settings.REDIS_URL)
    pattern = f"{django_settings.REDIS_PREFIX}racecraft:reward-validation:*"
    for key in client.scan_iter(pattern):
        client.delete(key)
    client.close()
    celery_app.control.purge()


@pytest.fixture
def alice_client(db) -> Client:
    client = Client()
    client.force_login(get_user_model().objects.create_user("alice", password="x-9-y-8-z"))
    return client


@pytest.fixture
def charlie_client(db) -> Client:
    client = Client()
    client.force_login(get_user_model().objects.create_user("charlie", password="x-9-y-8-z"))
    return client


@pytest.fixture
def worker(redis_env: dict[str, str], tmp_path: Path) -> Iterator[ChildProcess]:
    env = {**os.environ, **redis_env, "DJANGO_SETTINGS_MODULE": "console.settings"}
    with celery_worker_process(
        queues=["interactive"], env=env, log_path=tmp_path / "worker.log"
    ) as process:
        yield process


def start(client: Client, source: str, track: str = "racecraft_oval"):
    payload = json.dumps({"source": source, "track": track})
    return client.post(URL, payload, content_type="application/json")


def wait_done(client: Client, poll: str, seconds: float = 120.0) -> dict:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        body = client.get(poll).json()
        if body["status"] == "done":
            return body
        time.sleep(0.2)
    raise AssertionError("the validation never finished")


def test_static_errors_are_answered_at_once_and_nothing_is_queued(alice_client) -> None:
    response = start(alice_client, "import os\n\ndef reward_function(params):\n    return 1\n")
    body = response.json()
    assert response.status_code == 200 and body["status"] == "done" and body["ok"] is False
    assert body["errors"][0]["type"] == "IMPORT_ERROR" and "id" not in body


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


def test_only_the_owner_can_read_a_validation(alice_client, charlie_client, settings) -> None:
    poll = start(alice_client, OK).json()["poll"]  # no worker: it stays queued
    assert alice_client.get(poll).json()["status"] == "queued"
    assert charlie_client.get(poll).status_code == 404
    assert alice_client.get(URL + "?id=not-a-real-id").status_code == 404


def test_concurrent_validations_per_user_are_limited(alice_client, charlie_client, settings):
    settings.RACECRAFT_VALIDATIONS_PER_USER = 1
    assert start(alice_client, OK).status_code == 202  # no worker: it stays queued
    refused = start(alice_client, OK)
    assert (
        refused.status_code == 429
        and "validations running" in refused.json()["errors"][0]["message"]
    )
    assert start(charlie_client, OK).status_code == 202  # Charlie has his own allowance


def test_validations_per_minute_are_limited(alice_client, settings) -> None:
    settings.RACECRAFT_VALIDATIONS_PER_USER = 10
    settings.RACECRAFT_VALIDATIONS_PER_MINUTE = 2
    codes = [start(alice_client, OK).status_code for _ in range(3)]
    assert codes[:2] == [202, 202] and codes[2] == 429


def _elif_table(branches: int) -> str:
    lines = ["def reward_function(params):", "    x = int(params['steps'])", "    if x == 0:"]
    lines.append("        return 0.5")
    for i in range(1, branches):
        lines += [f"    elif x == {i}:", f"        return {1 + i / branches}"]
    return "\n".join([*lines, "    return 1.0", ""])


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
