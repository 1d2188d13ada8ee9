"""Starting a readiness check (issue 51): only the owner, only a trained and idle model, inside
the quota and queued on its own queue; the compare page's rules; the fair order counts it.
(Alice owns things; Charlie must never touch them.)"""

from __future__ import annotations

import pytest

from tests.training.services.factory import create
from training import dispatch, services
from training.models import EvaluationJob, JobStatus, RacingModel, ReadinessCheck
from training.services import ServiceError
from training.services.readiness import (
    readiness_compare,
    readiness_finished_models,
    readiness_rows,
    readiness_start,
    readiness_video,
)

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


def trained(owner, name: str = "m1") -> RacingModel:
    model = create(owner, name=name)
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    model.refresh_from_db()
    return model


def test_a_check_is_queued_on_its_own_queue(alice, monkeypatch, django_capture_on_commit_callbacks):
    sent = []
    monkeypatch.setattr(dispatch, "send", lambda name, pk: sent.append((name, pk)) or "t")
    model = trained(alice)
    with django_capture_on_commit_callbacks(execute=True):
        check = readiness_start(model=model, user=alice)
    assert sent == [(dispatch.CHECK_READINESS, check.pk)]
    check.refresh_from_db()
    assert check.task_id == "t" and check.status == JobStatus.QUEUED
    assert (check.track_id, check.direction) == ("racecraft_oval", model.direction)
    assert check.plan["strengths"] == [0.33, 0.67, 1.0] and check.cells_total == 16
    model.refresh_from_db()
    assert model.status == RacingModel.Status.EVALUATING and model.is_busy
    assert services.jobs_ahead(check) == 0  # in the fair order as an evaluation is
    from console.celery import app

    assert app.amqp.router.route({}, dispatch.CHECK_READINESS)["queue"].name == "readiness"


def test_refusals_are_clear(alice, charlie, settings):
    model = trained(alice)
    with pytest.raises(ServiceError, match="not found"):
        readiness_start(model=model, user=charlie, enqueue=False)
    untrained = create(alice, name="fresh")
    with pytest.raises(ServiceError, match="train this model before checking its readiness"):
        readiness_start(model=untrained, user=alice, enqueue=False)
    with pytest.raises(ServiceError, match="strengths"):
        readiness_start(model=model, user=alice, plan={"strengths": [2]}, enqueue=False)
    with pytest.raises(ServiceError, match="unknown track"):
        readiness_start(model=model, user=alice, track_id="atlantis", enqueue=False)
    assert not ReadinessCheck.objects.exists()


def test_the_quota_counts_checks_and_a_busy_model_waits(alice, settings):
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 2
    first, second, third = trained(alice, "a"), trained(alice, "b"), trained(alice, "c")
    readiness_start(model=first, user=alice, enqueue=False)
    with pytest.raises(ServiceError, match="busy"):
        readiness_start(model=first, user=alice, enqueue=False)
    with pytest.raises(ServiceError, match="busy"):  # an evaluation waits for the check too
        services.evaluation_start(model=first, user=alice, enqueue=False)
    services.evaluation_start(model=second, user=alice, enqueue=False)
    with pytest.raises(ServiceError, match="2 jobs queued or running"):
        readiness_start(model=third, user=alice, enqueue=False)
    assert ReadinessCheck.objects.count() == 1 and EvaluationJob.objects.count() == 1


def test_stopping_a_queued_check_cancels_it_and_frees_the_model(alice):
    model = trained(alice)
    check = readiness_start(model=model, user=alice, enqueue=False)
    with pytest.raises(ServiceError, match="not found"):
        services.job_stop(job=check, user=None)
    services.job_stop(job=check, user=alice)
    check.refresh_from_db()
    model.refresh_from_db()
    assert check.status == JobStatus.CANCELED and model.status == RacingModel.Status.READY


def finished(model, cells: list[dict], videos=()) -> ReadinessCheck:
    return ReadinessCheck.objects.create(
        model=model, track_id=model.track_id, status=JobStatus.COMPLETED, verdict="Ready",
        plan={"families": ["light"], "strengths": [0.5]}, videos=list(videos),
        results={"cells": cells, "worst": ["light-0_5"]},
    )  # fmt: skip


CELLS = [{"family": "clean", "strength": 0.0, "completion_pct": 100.0},
         {"family": "light", "strength": 0.5, "completion_pct": 50.0}]  # fmt: skip


def test_compare_only_your_own_finished_checks(alice, charlie):
    mine, other, theirs = trained(alice, "a"), trained(alice, "b"), trained(charlie, "c")
    finished(mine, CELLS)
    finished(theirs, CELLS)
    assert readiness_finished_models(alice) == [mine]
    with pytest.raises(ServiceError, match="no finished readiness check"):
        readiness_compare(user=alice, model_ids=[mine.pk, other.pk])
    with pytest.raises(ServiceError, match="not found"):
        readiness_compare(user=alice, model_ids=[mine.pk, theirs.pk])
    with pytest.raises(ServiceError, match="two different"):
        readiness_compare(user=alice, model_ids=[mine.pk, mine.pk])
    finished(other, CELLS[:1])
    pairs = readiness_compare(user=alice, model_ids=[mine.pk, other.pk])
    rows = readiness_rows([c for _, c in pairs])
    assert [r["key"] for r in rows] == ["clean-0", "light-0_5"]
    assert rows[1]["cells"][0]["completion_pct"] == 50.0 and rows[1]["cells"][1] is None


def test_a_video_is_served_only_when_the_check_recorded_it(alice):
    check = finished(trained(alice), CELLS, videos=["light-0_5"])
    with pytest.raises(ServiceError, match="no such video"):
        readiness_video(check, "../../etc")
    with pytest.raises(ServiceError, match="could not be read"):
        readiness_video(check, "light-0_5")  # recorded, but not in this test's store
