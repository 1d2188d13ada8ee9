"""A training job on streamed simulation (issue 14) through real components: a Celery worker
runs the trainer on the ``training`` queue and two simulation workers on the ``simulation``
queue (``RACECRAFT_SIMULATION=streams``, ``RACECRAFT_REMOTE_ROLLOUT_SLOTS=2``), Redis carries
the experience, the store the checkpoints, and the live group the frames with what they show."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator

import pytest
from asgiref.sync import async_to_sync
from channels.layers import get_channel_layer
from django.contrib.auth import get_user_model

from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from tests.support import ChildProcess, celery_worker_process
from training import live, services
from training.models import IterationMetric, JobStatus, RacingModel, TrainingJob
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]


@pytest.fixture
def streamed_worker(child_env, tmp_path) -> Iterator[ChildProcess]:
    env = {**child_env, "RACECRAFT_SIMULATION": "streams", "RACECRAFT_REMOTE_ROLLOUT_SLOTS": "2"}
    with celery_worker_process(queues=["training", "simulation"], env=env, concurrency=3,
                               log_path=tmp_path / "worker.log") as worker:  # fmt: skip
        yield worker


def wait_for(predicate, timeout: float, what: str, worker: ChildProcess):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    pytest.fail(f"timed out waiting for {what}\n{worker.log()[-4000:]}")


async def first_frame(group: str, timeout: float) -> dict | None:
    """The first ``job.frame`` message the job's group gets, watching as the page does."""
    layer = get_channel_layer()
    channel = await layer.new_channel()
    await layer.group_add(group, channel)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        live.mark_watching(group)  # as the open page does
        try:
            message = await asyncio.wait_for(layer.receive(channel), timeout=2.0)
        except TimeoutError:
            continue
        if message.get("type") == "job.frame":
            return message
    return None


def test_a_streamed_job_trains_evaluates_and_streams_frames(streamed_worker, store_dir):
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    model = services.model_create(
        owner=alice, name="streamed", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function=REWARD, max_minutes=30, seed=1,
        hyperparameters={"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32},
    )  # fmt: skip
    job = services.training_start(model=model, user=alice)
    group = live.job_group("training", job.pk)
    frame = async_to_sync(first_frame)(group, 600)
    assert frame is not None, "no live frame within 600 s"
    assert frame["phase"] in ("training", "evaluation") and frame["camera"]
    assert isinstance(frame["iteration"], int) and isinstance(frame["version"], int)

    wait_for(lambda: TrainingJob.objects.get(pk=job.pk).iterations >= 2, 900,
             "two training iterations", streamed_worker)  # fmt: skip
    services.job_stop(job=TrainingJob.objects.get(pk=job.pk), user=alice)
    job = wait_for(
        lambda: TrainingJob.objects.filter(pk=job.pk, status=JobStatus.COMPLETED).first(),
        180, "the stopped job to complete", streamed_worker,
    )  # fmt: skip
    model.refresh_from_db()
    assert model.status == RacingModel.Status.READY and model.has_checkpoint
    points = list(IterationMetric.objects.filter(job=job).order_by("iteration"))
    assert [p.iteration for p in points] == list(range(1, len(points) + 1))
    assert all(p.episodes == 4 for p in points)
    assert job.episode_metrics.filter(phase="training").count() == job.episodes
    assert job.episodes >= 4 * len(points)
    assert get_store().get_bytes(keys_for(model.pk).last)
