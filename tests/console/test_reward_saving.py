"""Create, clone and reward edit never run reward code in the web process (issue 10): a
function the user has just validated saves at once; any other is validated on a worker
while the page shows the progress (202, the form as posted), then saves when posted again.

The web side of every test here runs with the sandbox's one way to start a child process
patched to fail the test, so any reward code run by the web process is caught."""

from __future__ import annotations

import html
import json
import time

import pytest
from celery import current_app
from django.contrib.auth import get_user_model
from django.test import Client

from tests.console.conftest import REWARD, make_model
from tests.console.test_model_views import create_data
from tests.support import celery_worker_process
from training.models import RacingModel
from training.sandbox.process import SandboxProcess
from training.services import rewards

pytestmark = pytest.mark.django_db

RUNTIME_ERROR = "def reward_function(params):\n    x = 1\n    return params['nope']\n"
POLL_TIMEOUT_S = 180.0
"""How long a validation on the test's worker may take (a loaded machine is slow)."""


@pytest.fixture(autouse=True)
def no_sandbox_in_this_process(monkeypatch, settings) -> None:
    """Starting a sandbox child here (the web process in these tests) fails the test."""

    def refuse(self, *args, **kwargs):
        raise AssertionError("the web process started a sandbox child")

    monkeypatch.setattr(SandboxProcess, "start", refuse)
    settings.RACECRAFT_VALIDATIONS_PER_USER = 100  # validations may stay queued here
    settings.RACECRAFT_VALIDATIONS_PER_MINUTE = 100


def pending_poll(response) -> str:
    """The poll URL of the validation a 202 page waits for."""
    assert response.status_code == 202, response.content.decode()[:2000]
    page = response.content.decode()
    assert 'id="pending-validation"' in page
    start = page.index('data-pending-poll="') + len('data-pending-poll="')
    return html.unescape(page[start : page.index('"', start)])


def wait_done(client: Client, poll: str) -> dict:
    deadline = time.monotonic() + POLL_TIMEOUT_S
    while True:
        body = client.get(poll).json()
        if body["status"] == "done":
            return body
        assert time.monotonic() < deadline, f"the validation did not finish: {body}"
        time.sleep(0.2)


def test_a_create_waits_for_a_validation_without_blocking_then_saves(
    alice, alice_client, store_dir, child_env, tmp_path
) -> None:
    data = create_data(name="waits", description="Kept while validating")
    # No worker yet: the validation cannot finish, yet the request answers at once.
    response = alice_client.post("/models/new/", data)
    poll = pending_poll(response)
    page = html.unescape(response.content.decode())
    assert 'value="waits"' in page and "Kept while validating" in page  # nothing lost
    assert 'data-jump="step-reward"' in page
    assert not RacingModel.objects.exists()  # nothing saved before it passes
    # Other requests go on meanwhile: pages, and another user's validation.
    assert alice_client.get("/models/").status_code == 200
    assert alice_client.get(poll).json() == {"status": "queued"}
    assert alice_client.post("/models/new/", data).status_code == 202
    # Charlie cannot read Alice's validation.
    other = Client()
    other.force_login(get_user_model().objects.create_user("charlie", password="x-charlie-1"))
    assert other.get(poll).status_code == 404

    with celery_worker_process(
        queues=["interactive"], env=child_env, log_path=tmp_path / "worker.log"
    ):
        assert wait_done(alice_client, poll)["ok"] is True
    # Posted again (as the page does once it passes): saved at once, no second validation.
    response = alice_client.post("/models/new/", data)
    model = RacingModel.objects.get(owner=alice, name="waits")
    assert response.status_code == 302 and response["Location"] == f"/models/{model.pk}/"
    assert model.description == "Kept while validating"


def test_errors_from_the_worker_come_with_their_lines(
    alice, alice_client, store_dir, child_env, tmp_path
) -> None:
    model = make_model(alice)
    url = f"/models/{model.pk}/reward/"
    poll = pending_poll(alice_client.post(url, {"reward_function": RUNTIME_ERROR}))
    with celery_worker_process(
        queues=["interactive"], env=child_env, log_path=tmp_path / "worker.log"
    ):
        body = wait_done(alice_client, poll)
    assert body["ok"] is False
    (error,) = [e for e in body["errors"] if e.get("lineNumber")]
    assert error["lineNumber"] == 3 and "nope" in error["message"]
    # Not passed: posting again validates again instead of saving.
    assert alice_client.post(url, {"reward_function": RUNTIME_ERROR}).status_code == 202
    model.refresh_from_db()
    assert model.reward_function == REWARD


def test_a_function_validated_with_the_button_saves_at_once(alice, alice_client, store_dir):
    """A pass recorded by the worker (here written as the worker writes it) for this user,
    source, track and direction saves without another validation; CRLF from a text box is
    the same source."""
    source = "def reward_function(params):\n    return 0.25\n"
    rewards.reward_validation_remember(
        user_id=alice.pk, source=source, track_id="racecraft_oval", direction="native"
    )
    posted = source.replace("\n", "\r\n")
    response = alice_client.post("/models/new/", create_data(name="quick", reward_function=posted))
    assert response.status_code == 302
    # Another direction, or another user, needs its own validation.
    assert (
        alice_client.post(
            "/models/new/", create_data(name="other-way", reward_function=source, direction="cw")
        ).status_code
        == 202
    )
    assert not rewards.reward_validation_passed(
        user_id=alice.pk + 1, source=source, track_id="racecraft_oval", direction="native"
    )


def test_clone_and_reward_edit_queue_a_validation_too(alice, alice_client, store_dir) -> None:
    model = make_model(alice)
    clone_data = {"name": "clone-one", "description": "", "track_id": "racecraft_oval",
                  "direction": "native", "reward_function": REWARD,
                  "max_minutes": "10"}  # fmt: skip
    pending_poll(alice_client.post(f"/models/{model.pk}/clone/", clone_data))
    pending_poll(alice_client.post(f"/models/{model.pk}/reward/", {"reward_function": REWARD}))
    assert RacingModel.objects.filter(owner=alice).count() == 1
    rewards.reward_validation_remember(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval", direction="native"
    )
    response = alice_client.post(f"/models/{model.pk}/clone/", clone_data)
    assert response.status_code == 302
    assert RacingModel.objects.filter(owner=alice, name="clone-one").exists()


def test_parse_errors_and_limits_answer_at_once(alice_client, store_dir, settings) -> None:
    broken = "def reward_function(params):\n    return (\n"
    response = alice_client.post("/models/new/", create_data(reward_function=broken))
    assert response.status_code == 400
    assert 'id="pending-validation"' not in response.content.decode()
    settings.RACECRAFT_VALIDATIONS_PER_USER = 1
    alice_client.post("/models/new/", create_data(name="first"))
    refused = alice_client.post("/models/new/", create_data(name="second"))
    assert refused.status_code == 400
    assert "validations running; wait for one to finish" in refused.content.decode()


def test_the_validate_api_and_the_save_share_one_pass(alice, alice_client, monkeypatch):
    """The Validate button's validation carries the user, so its pass is the one a save
    reads (the worker's side: tests/training/services/test_reward_validation_pass.py)."""
    sent: list[dict] = []
    monkeypatch.setattr(current_app, "send_task", lambda name, **kw: sent.append(kw["kwargs"]))
    body = alice_client.post(
        "/api/reward/validate",
        json.dumps({"source": REWARD, "track": "racecraft_oval"}),
        content_type="application/json",
    )
    assert body.status_code == 202
    assert sent == [{"source": REWARD, "track_id": "racecraft_oval", "direction": "native",
                     "user_id": alice.pk}]  # fmt: skip
