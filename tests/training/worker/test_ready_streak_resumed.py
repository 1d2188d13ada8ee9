"""A training job retried after its worker was lost carries its "stop when ready" streak on
(the latest of its recorded iterations in a row at 100 %) and says so with what it resumed
from; a new job of a model whose last one failed, and a job that cannot resume its own last
checkpoint, count from 0."""

from __future__ import annotations

import pytest

from training import services
from training.models import IterationMetric, JobStatus, RacingModel, TrainingJob
from training.store import get_store, keys_for
from training.worker import training as worker_training

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"


def trained(owner, progress: list[float], *, ready: int = 3, stored: bool = True
            ) -> tuple[RacingModel, TrainingJob]:  # fmt: skip
    """A model whose job recorded evaluations at ``progress`` % and (``stored``) its last
    checkpoint."""
    name = f"ready-{RacingModel.objects.count()}"
    model = services.model_create(owner=owner, name=name, track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False, stop_when_ready=ready)  # fmt: skip
    job = services.training_start(model=model, user=owner, enqueue=False)
    for i, p in enumerate(progress, start=1):
        IterationMetric.objects.create(job=job, iteration=i, episodes=4, steps=100,
                                       total_steps=100 * i, train_reward=1.0, train_progress=50.0,
                                       eval_progress=p, elapsed_s=10.0 * i)  # fmt: skip
    TrainingJob.objects.filter(pk=job.pk).update(iterations=len(progress))
    if stored:
        get_store().put_bytes(keys_for(model.pk).last, b"LAST")
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    return model, job


def started(monkeypatch, job: TrainingJob):
    """The config the loop would be given for ``job`` (stopped there) and the job after."""
    seen = []

    def train(config, hooks):
        seen.append(config)
        raise RuntimeError("enough")

    monkeypatch.setattr(worker_training, "train", train)
    assert worker_training.run_training_job(job.pk, "test") == "failed"
    return seen[0], TrainingJob.objects.get(pk=job.pk)


def test_a_retried_job_carries_its_streak_on(alice, monkeypatch) -> None:
    _, job = trained(alice, [100.0, 40.0, 100.0, 100.0])
    config, job = started(monkeypatch, job)
    assert config.initial_checkpoint == b"LAST"
    assert config.stop_when_ready == 3 and config.clean_streak == 2
    assert job.resumed_from.startswith("resumed from its own last checkpoint (iteration 4)")
    assert job.resumed_from.endswith("; ready streak 2 of 3 carried on")


def test_without_its_own_checkpoint_or_the_setting_the_count_starts_at_0(alice, monkeypatch):
    _, job = trained(alice, [100.0, 100.0], stored=False)  # lost: a new network, count from 0
    config, job = started(monkeypatch, job)
    assert config.initial_checkpoint is None and config.clean_streak == 0
    assert "ready streak" not in job.resumed_from

    _, job = trained(alice, [100.0, 100.0], ready=0)
    config, _ = started(monkeypatch, job)
    assert config.initial_checkpoint == b"LAST" and config.clean_streak == 0


def test_a_new_job_of_a_failed_model_starts_its_own_count(alice, monkeypatch) -> None:
    model, first = trained(alice, [100.0, 100.0])
    TrainingJob.objects.filter(pk=first.pk).update(status=JobStatus.FAILED)
    RacingModel.objects.filter(pk=model.pk).update(status=RacingModel.Status.ERROR)
    second = services.training_start(model=model, user=alice, enqueue=False)
    config, second = started(monkeypatch, second)
    assert config.initial_checkpoint == b"LAST" and config.clean_streak == 0
    assert second.resumed_from.startswith(f"resumed from job #{first.pk}'s last checkpoint")
    assert "ready streak" not in second.resumed_from
