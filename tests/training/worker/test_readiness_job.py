"""A readiness check as a job (issue 51), through the worker's own path (as the evaluation
jobs' tests run it): the table and verdict recorded, the worst cells' MP4s in the model's folder
of the store, served to the owner only; a checkpoint that cannot be read fails it in words."""

from __future__ import annotations

import pytest
from django.test import Client

from training.models import JobStatus, RacingModel, ReadinessCheck
from training.services.readiness import readiness_start, readiness_video_key
from training.store import get_store, keys_for
from training.worker.readiness import run_readiness_check

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]
ACTIONS = [{"steering_angle": a, "speed": s} for a in (-30, 0, 30) for s in (1.0, 2.0)]
SMALL = {"families": ["light", "car"], "strengths": [0.5, 1.0], "laps": 1}


def test_a_check_records_its_table_and_the_owner_gets_its_videos(racer_model, charlie):
    model = racer_model("alice", ACTIONS)
    check = readiness_start(model=model, user=model.owner, plan=SMALL, enqueue=False)
    assert run_readiness_check(check.pk, "test") == "completed"
    check = ReadinessCheck.objects.get(pk=check.pk)
    assert check.status == JobStatus.COMPLETED and check.cells_done == check.cells_total == 5
    assert [c["family"] for c in check.cells] == ["clean", "light", "light", "car", "car"]
    assert all(c["laps_attempted"] == 1 for c in check.cells)
    # An untrained network does not drive: the plain rules say so.
    assert check.ready is False and check.verdict.startswith("Not ready")
    assert check.videos == sorted(check.results["worst"]) and len(check.videos) == 2
    for key in check.videos:
        stored = readiness_video_key(check, key)
        assert stored.startswith(keys_for(model.pk).prefix) and get_store().exists(stored)
    model.refresh_from_db()
    assert model.status == RacingModel.Status.READY

    owner, stranger = Client(), Client()
    owner.force_login(model.owner)
    stranger.force_login(charlie)
    url = f"/readiness/{check.pk}/video/{check.videos[0]}.mp4"
    response = owner.get(url)
    assert response.status_code == 200 and response["Content-Type"] == "video/mp4"
    assert b"".join(response.streaming_content)[4:8] == b"ftyp"
    assert stranger.get(url).status_code == 404
    assert owner.get(f"/readiness/{check.pk}/video/clean-0.mp4").status_code == 404
    page = owner.get(f"/models/{model.pk}/").content.decode()
    assert 'id="readiness-table"' in page and check.verdict.split(":")[0] in page
    assert url in page
    assert stranger.get(f"/models/{model.pk}/").status_code == 404


def test_a_checkpoint_that_cannot_be_read_fails_the_check_in_words(racer_model):
    model = racer_model("alice", ACTIONS)
    get_store().put_bytes(keys_for(model.pk).best, b"not a checkpoint")
    check = readiness_start(model=model, user=model.owner, plan=SMALL, enqueue=False)
    assert run_readiness_check(check.pk, "test") == "failed"
    check.refresh_from_db()
    assert check.status == JobStatus.FAILED and check.error
    assert "Traceback" not in check.error and check.videos == []
    model.refresh_from_db()
    assert model.status == RacingModel.Status.READY  # its checkpoint is still there


def test_a_stop_asked_for_ends_the_check_with_what_it_measured(racer_model):
    model = racer_model("alice", ACTIONS)
    check = readiness_start(model=model, user=model.owner, plan=SMALL, enqueue=False)
    ReadinessCheck.objects.filter(pk=check.pk).update(stop_requested=True)
    assert run_readiness_check(check.pk, "test") == "completed"
    check.refresh_from_db()
    assert check.status == JobStatus.COMPLETED and check.results["stopped"]
    assert (check.verdict, check.ready, check.videos) == ("Stopped", None, [])
