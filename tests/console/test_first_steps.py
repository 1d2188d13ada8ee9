"""What a new user trips over (issue #16), at the level of the pages and the services: the
model page after training, evaluation numbers, editing the reward function before the first
training, copying a failed model, the stop confirmation, login and sign-up."""

from __future__ import annotations

import pytest
from django.test import Client

from tests.conftest import PASSWORD
from tests.console.conftest import make_model
from training import services
from training.models import EvaluationJob, JobStatus, RacingModel, TrainingJob
from training.services import rewards

pytestmark = pytest.mark.django_db

GOOD = "def reward_function(params):\n    return 0.5\n"


def _finished_job(model: RacingModel, status: str = JobStatus.COMPLETED, error: str = ""):
    return TrainingJob.objects.create(model=model, max_minutes=2, status=status, error=error)


def test_after_training_the_page_has_no_empty_video_boxes(alice_model, alice_client) -> None:
    _finished_job(alice_model)
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert 'id="training-video"' not in page and 'id="video-note"' in page
    assert 'class="live-grid single"' in page


def test_during_training_the_video_is_there_and_stop_asks_first(alice_model, alice_client) -> None:
    job = _finished_job(alice_model, status=JobStatus.IN_PROGRESS)
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert 'id="training-video"' in page
    assert 'id="stop-confirm"' in page and 'id="stop-training-confirm"' in page
    assert f'action="/jobs/training/{job.pk}/stop/"' in page


def test_a_failed_training_shows_its_error_once(alice_model, alice_client) -> None:
    message = "reward_function raised KeyError at step 3: 'nope'"
    _finished_job(alice_model, status=JobStatus.FAILED, error=message)
    RacingModel.objects.filter(pk=alice_model.pk).update(status="ERROR", error=message)
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert page.count("KeyError at step 3") == 1
    assert "Copy as new model" in page


def test_evaluations_are_numbered_per_model(alice, alice_client, store_dir) -> None:
    first = make_model(alice, "first-model")
    second = make_model(alice, "second-model")
    for model in (first, first, second):
        EvaluationJob.objects.create(model=model, track_id="racecraft_oval")
    page = alice_client.get(f"/models/{second.pk}/").content.decode()
    assert "Evaluation #1" in page
    page = alice_client.get(f"/models/{first.pk}/").content.decode()
    assert "Evaluation #2" in page and "#1 ·" in page


def test_the_reward_can_be_edited_until_training_starts(alice_model, alice_client) -> None:
    url = f"/models/{alice_model.pk}/reward/"
    assert 'id="edit-reward"' in alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    bad = alice_client.post(url, {"reward_function": "def reward_function(p):\n    return p[\n"})
    assert bad.status_code == 400 and "SYNTAX_ERROR" in bad.content.decode()
    # Validated on a worker first (the page's way there: tests/console/test_reward_saving.py).
    rewards.reward_validation_remember(
        user_id=alice_model.owner_id, source=GOOD, track_id="racecraft_oval", direction="native"
    )
    response = alice_client.post(url, {"reward_function": GOOD})
    assert response.status_code == 302
    alice_model.refresh_from_db()
    assert alice_model.reward_function == GOOD
    _finished_job(alice_model)
    refused = alice_client.post(url, {"reward_function": GOOD + "# again\n"})
    assert refused.status_code == 400 and "clone the model" in refused.content.decode()
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert 'id="edit-reward"' not in page


def test_a_failed_model_without_checkpoint_is_copied_fresh(alice, alice_model) -> None:
    RacingModel.objects.filter(pk=alice_model.pk).update(status="ERROR", error="boom")
    alice_model.refresh_from_db()
    copy = services.model_clone(model=alice_model, owner=alice, name="second-try",
                                reward_function=GOOD)  # fmt: skip
    assert not copy.has_checkpoint and copy.parent is None and copy.status == "READY"
    assert copy.action_space == alice_model.action_space and copy.reward_function == GOOD


def test_the_copy_page_says_it_starts_from_scratch(alice_model, alice_client) -> None:
    page = alice_client.get(f"/models/{alice_model.pk}/clone/").content.decode()
    assert 'id="fresh-copy-note"' in page and "trained from scratch" in page


def test_login_lands_on_the_models_and_signup_rules_are_compact(alice, client: Client) -> None:
    page = client.get("/accounts/signup/").content.decode()
    assert 'class="help password-rules"' in page and "<ul>" not in page
    response = client.post("/accounts/login/", {"username": "alice", "password": PASSWORD})
    assert response.status_code == 302 and response["Location"] == "/models/"


def test_the_favicon_is_linked(client: Client) -> None:
    page = client.get("/").content.decode()
    assert 'rel="icon"' in page


def test_the_admin_lists_models_and_jobs_read_only(alice_model, client: Client) -> None:
    from django.contrib.auth import get_user_model

    admin = get_user_model().objects.create_superuser("root", password=PASSWORD)
    client.force_login(admin)
    job = _finished_job(alice_model, status=JobStatus.FAILED, error="boom")
    listing = client.get("/admin/training/racingmodel/?status__exact=READY&q=alice")
    assert listing.status_code == 200 and "alice-oval" in listing.content.decode()
    jobs = client.get("/admin/training/trainingjob/?status__exact=FAILED").content.decode()
    assert "alice-oval" in jobs
    change = client.get(f"/admin/training/trainingjob/{job.pk}/change/").content.decode()
    assert 'name="status"' not in change and "boom" in change  # shown, not editable
    assert client.get("/admin/training/trainingjob/add/").status_code == 403
    assert client.get("/favicon.ico").status_code == 301
