"""Starting a job while the broker is down (issue #15): the job is saved and stays queued, the
page says so, and the reaper sends its task once the broker answers again - through the real
broker (the session's Redis), made unreachable by pointing the Celery app at a dead socket."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from django.contrib.auth import get_user_model
from django.utils import timezone

from console.celery import app as celery_app
from console.redisconf import celery_url
from tests.console.conftest import make_model
from tests.faults.test_jobs_recovery import _purge_job_queues
from tests.faults.test_worker_faults import _reset_broker_pools
from training import dispatch, services
from training.models import JobStatus, RacingModel, TrainingJob

pytestmark = pytest.mark.django_db(transaction=True)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[dict[str, object]]:
    """``down()`` points the Celery app at a socket nobody listens on; ``up()`` back at the
    session's Redis."""
    saved = celery_app.conf.broker_url
    dead = celery_url(f"unix://{tmp_path / 'nobody.sock'}?db=0")

    def point(url: str) -> None:
        celery_app.conf.broker_url = url
        _reset_broker_pools()

    try:
        yield {"down": lambda: point(dead), "up": lambda: point(saved)}
    finally:
        point(saved)


def test_a_job_started_while_the_broker_is_down_stays_queued_and_is_sent_later(
    client, store_dir, broker, redis_url
) -> None:
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    client.force_login(alice)
    model = make_model(alice)
    broker["down"]()
    response = client.post(f"/models/{model.pk}/train/", follow=True)
    assert response.status_code == 200
    page = response.content.decode()
    assert "cannot be reached right now" in page and "stays queued" in page
    job = TrainingJob.objects.get(model=model)
    assert job.status == JobStatus.QUEUED and job.task_id == "" and job.error == ""
    assert RacingModel.objects.get(pk=model.pk).status == RacingModel.Status.QUEUED
    # Long enough ago for the reaper; while the broker is down it can do nothing either.
    old = timezone.now() - timezone.timedelta(minutes=5)
    TrainingJob.objects.filter(pk=job.pk).update(created_at=old)
    assert services.jobs_reap_orphans() == 0
    assert TrainingJob.objects.get(pk=job.pk).status == JobStatus.QUEUED

    broker["up"]()
    try:
        assert services.jobs_reap_orphans() == 1
        sent = TrainingJob.objects.get(pk=job.pk)
        assert sent.status == JobStatus.QUEUED and sent.task_id
        assert sent.task_id in (dispatch.queued_task_ids() or set())
    finally:
        _purge_job_queues(redis_url)
