"""A job's status reaches its live group only once the change is committed: a browser never
sees "completed" for a change the database may still roll back. (Alice owns the model.)"""

from __future__ import annotations

import pytest
from django.db import transaction

from tests.training.services.factory import create
from training import live, services
from training.models import JobStatus, TrainingJob

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


@pytest.fixture
def sent(monkeypatch) -> list[tuple[str, dict]]:
    messages: list[tuple[str, dict]] = []
    monkeypatch.setattr(live, "send", lambda group, message: messages.append((group, message)))
    return messages


@pytest.fixture
def running(alice) -> TrainingJob:
    model = create(alice)
    return TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)


def test_a_completed_job_is_broadcast_on_commit_only(
    running, sent, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks(execute=True):
        assert services.job_complete(job=running, stopped_by="user")
        assert sent == []  # committed yet? not until the outermost transaction ends
    assert sent == [(f"training-{running.pk}", {"type": "job.status", "status": "COMPLETED"})]


def test_a_rolled_back_change_is_never_broadcast(running, sent, django_capture_on_commit_callbacks):
    capture = django_capture_on_commit_callbacks(execute=True)
    with capture as callbacks, pytest.raises(RuntimeError), transaction.atomic():
        assert services.job_fail(job=running, error="boom")
        raise RuntimeError("the caller's transaction fails after the change")
    assert callbacks == [] and sent == []
    running.refresh_from_db()
    assert running.status == JobStatus.IN_PROGRESS


def test_a_stop_request_is_broadcast_on_commit(
    running, sent, alice, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks(execute=True):
        services.job_stop(job=running, user=alice)
        assert sent == []
    assert sent == [(f"training-{running.pk}", {"type": "job.status", "status": "STOPPING"})]
