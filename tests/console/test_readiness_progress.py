"""The readiness check's progress JSON, which the model page polls while a check runs: Alice
reads her check's; Charlie gets a 404 (as for a missing check); no session, the login page."""

from __future__ import annotations

import pytest
from django.test import Client

from training.models import JobStatus, RacingModel, ReadinessCheck

pytestmark = pytest.mark.django_db


@pytest.fixture
def check(alice_model) -> ReadinessCheck:
    RacingModel.objects.filter(pk=alice_model.pk).update(has_checkpoint=True)
    return ReadinessCheck.objects.create(
        model=alice_model, track_id="racecraft_oval", status=JobStatus.IN_PROGRESS,
        cells_done=3, cells_total=16,
    )  # fmt: skip


def test_the_owner_reads_how_far_the_check_got(check, alice_client):
    response = alice_client.get(f"/readiness/{check.pk}/progress.json")
    assert response.status_code == 200 and response["Cache-Control"] == "no-store"
    assert response.json() == {
        "status": "IN_PROGRESS", "status_display": "In progress", "badge": "busy",
        "active": True, "cells_done": 3, "cells_total": 16, "percent": 19, "ahead": None,
    }  # fmt: skip
    ReadinessCheck.objects.filter(pk=check.pk).update(status=JobStatus.COMPLETED, cells_done=16)
    done = alice_client.get(f"/readiness/{check.pk}/progress.json").json()
    assert done["active"] is False and done["percent"] == 100 and done["badge"] == "ok"
    ReadinessCheck.objects.filter(pk=check.pk).update(status=JobStatus.QUEUED, cells_done=0)
    queued = alice_client.get(f"/readiness/{check.pk}/progress.json").json()
    assert queued["active"] is True and queued["ahead"] == 0  # next to start


def test_nobody_else_reads_it(check, charlie_client):
    assert charlie_client.get(f"/readiness/{check.pk}/progress.json").status_code == 404
    assert charlie_client.get(f"/readiness/{check.pk + 99}/progress.json").status_code == 404
    anonymous = Client().get(f"/readiness/{check.pk}/progress.json")
    assert anonymous.status_code == 302 and "/login" in anonymous.url
    response = Client()
    response.force_login(check.model.owner)
    assert response.post(f"/readiness/{check.pk}/progress.json").status_code == 405


def test_the_model_page_polls_while_the_check_runs_and_says_to_reload_without_js(
    check, alice_client
):
    page = alice_client.get(f"/models/{check.model_id}/").content.decode()
    assert f'data-progress-url="/readiness/{check.pk}/progress.json"' in page
    assert "js/readiness_progress.js" in page
    assert "Reload the page to see how far it got." in page  # what a page without JS says
    ReadinessCheck.objects.filter(pk=check.pk).update(status=JobStatus.COMPLETED)
    page = alice_client.get(f"/models/{check.model_id}/").content.decode()
    assert "data-progress-url" not in page and "readiness_progress.js" not in page
