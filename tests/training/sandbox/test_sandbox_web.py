"""The web process runs no reward code: the Validate endpoint queues a Celery task and the
browser polls it; per-user limits. No worker runs here (a queued validation stays queued): the
validations a worker runs are test_sandbox_web_worker.py's, with one worker for its module."""

from __future__ import annotations

import json
import time

import pytest
import redis
from django.conf import settings as django_settings
from django.contrib.auth import get_user_model
from django.test import Client

from console.celery import app as celery_app

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
