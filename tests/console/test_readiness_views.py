"""The readiness pages (issue 51): the start button is a POST with CSRF, a refusal is said in
words, and Charlie never starts, stops, sees or compares Alice's checks."""

from __future__ import annotations

import pytest
from django.test import Client

from training import dispatch
from training.models import JobStatus, RacingModel, ReadinessCheck

pytestmark = pytest.mark.django_db


@pytest.fixture
def trained(alice_model) -> RacingModel:
    RacingModel.objects.filter(pk=alice_model.pk).update(has_checkpoint=True)
    alice_model.refresh_from_db()
    return alice_model


def test_start_and_stop_from_the_model_page(
    alice, trained, alice_client, charlie_client, monkeypatch, django_capture_on_commit_callbacks
):
    monkeypatch.setattr(dispatch, "send", lambda name, pk: "t")
    page = alice_client.get(f"/models/{trained.pk}/").content.decode()
    assert 'id="readiness"' in page and f'action="/models/{trained.pk}/readiness/"' in page
    assert 'id="download-readiness"' in page  # next to the car download
    strict = Client(enforce_csrf_checks=True)
    strict.force_login(alice)
    assert strict.post(f"/models/{trained.pk}/readiness/").status_code == 403
    assert charlie_client.post(f"/models/{trained.pk}/readiness/").status_code == 404
    assert alice_client.get(f"/models/{trained.pk}/readiness/").status_code == 405
    with django_capture_on_commit_callbacks(execute=True):
        response = alice_client.post(f"/models/{trained.pk}/readiness/", follow=True)
    check = ReadinessCheck.objects.get(model=trained)
    assert check.status == JobStatus.QUEUED
    assert "Readiness check queued." in response.content.decode()
    assert 'id="stop-readiness"' in response.content.decode()
    again = alice_client.post(f"/models/{trained.pk}/readiness/", follow=True).content.decode()
    assert "This model is busy" in again
    assert charlie_client.post(f"/readiness/{check.pk}/stop/").status_code == 404
    alice_client.post(f"/readiness/{check.pk}/stop/")
    check.refresh_from_db()
    assert check.status == JobStatus.CANCELED


def test_an_untrained_model_is_refused_in_words(alice_model, alice_client):
    page = alice_client.post(f"/models/{alice_model.pk}/readiness/", follow=True)
    assert "Train this model before checking its readiness" in page.content.decode()
    assert not ReadinessCheck.objects.exists()


def test_compare_shows_only_your_own_models(trained, alice_client, charlie_client):
    ReadinessCheck.objects.create(
        model=trained, track_id="racecraft_oval", status=JobStatus.COMPLETED, verdict="Ready",
        results={"cells": [{"family": "clean", "strength": 0.0, "completion_pct": 100.0}]},
    )  # fmt: skip
    assert trained.name in alice_client.get("/readiness/compare/").content.decode()
    theirs = charlie_client.get("/readiness/compare/")
    assert theirs.status_code == 200 and trained.name not in theirs.content.decode()
    refused = charlie_client.get(f"/readiness/compare/?a={trained.pk}&b={trained.pk + 1}")
    assert refused.status_code == 400 and trained.name not in refused.content.decode()
    assert alice_client.get("/readiness/compare/?a=x&b=").status_code == 400
