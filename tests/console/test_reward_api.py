"""POST /api/reward/validate: the Validate button's endpoint. Static errors come back at once;
anything to run is queued for a worker and polled (run end to end in
tests/training/test_sandbox_web.py)."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.django_db
URL = "/api/reward/validate"


@pytest.fixture(autouse=True)
def _room_for_queued_validations(settings) -> None:
    settings.RACECRAFT_VALIDATIONS_PER_USER = 100  # no worker here: validations stay queued
    settings.RACECRAFT_VALIDATIONS_PER_MINUTE = 100


def post(client, payload) -> tuple[int, dict]:
    response = client.post(URL, json.dumps(payload), content_type="application/json")
    return response.status_code, response.json()


def test_errors_come_with_their_line_numbers(alice_client) -> None:
    broken = "def reward_function(params):\n    x = 1\n    return x +\n"
    status, body = post(alice_client, {"source": broken, "track": "racecraft_oval"})
    assert status == 200 and body["ok"] is False
    assert body["errors"][0]["type"] == "SYNTAX_ERROR" and body["errors"][0]["lineNumber"] == 3

    runtime = "def reward_function(params):\n\n    return params['no_such_key']\n"
    status, body = post(alice_client, {"source": runtime, "track": "racecraft_oval"})
    assert status == 202 and body["status"] == "queued"  # only a worker runs it

    imports = "import os\n\ndef reward_function(params):\n    return 1.0\n"
    status, body = post(alice_client, {"source": imports, "track": "racecraft_oval"})
    assert body["errors"][0]["type"] == "IMPORT_ERROR" and body["errors"][0]["lineNumber"] == 1


def test_a_good_function_passes(alice_client) -> None:
    source = "def reward_function(params):\n    return float(params['progress']) / 100 + 1e-3\n"
    status, body = post(alice_client, {"source": source, "track": "racecraft_oval",
                                       "direction": "cw"})  # fmt: skip
    assert status == 202 and body["status"] == "queued"
    assert alice_client.get(body["poll"]).json() == {"status": "queued"}


def test_bad_requests_are_answered_clearly(alice_client) -> None:
    bad_json = alice_client.post(URL, "{not json", content_type="application/json")
    assert (
        bad_json.status_code == 400 and "not valid JSON" in bad_json.json()["errors"][0]["message"]
    )
    status, body = post(alice_client, {"source": "x", "track": "no_such_track"})
    assert status == 400 and "unknown track" in body["errors"][0]["message"].lower()
    status, body = post(alice_client, {"track": "racecraft_oval"})
    assert status == 400 and body["errors"][0]["field"] == "source"
    status, body = post(alice_client, {"source": "  ", "track": "racecraft_oval"})
    assert status == 400 and "Write a reward function" in body["errors"][0]["message"]
    assert alice_client.get(URL).status_code == 404  # GET polls; without an id, nothing
    assert alice_client.put(URL).status_code == 405


def test_signed_in_only_and_csrf(client, alice) -> None:
    assert client.post(URL, "{}", content_type="application/json").status_code == 302
    from django.test import Client

    strict = Client(enforce_csrf_checks=True)
    strict.force_login(alice)
    response = strict.post(URL, json.dumps({"source": "x", "track": "racecraft_oval"}),
                           content_type="application/json")  # fmt: skip
    assert response.status_code == 403
