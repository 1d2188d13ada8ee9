"""A training job retried after its worker was lost carries its "stop when ready" streak on
(the latest of its recorded iterations in a row at 100 %), and says so with what it resumed
from; a new job of a model whose last one failed starts its own count."""

from __future__ import annotations

import pytest

from training import services
from training.models import IterationMetric, JobStatus, RacingModel, TrainingJob
from training.worker import training as worker_training

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"


def record(job: TrainingJob, progress: list[float]) -> None:
    for i, p in enumerate(progress, start=1):
        IterationMetric.objects.create(job=job, iteration=i, episodes=4, steps=100,
                                       total_steps=100 * i, train_reward=1.0, train_progress=50.0,
                                       eval_progress=p, elapsed_s=10.0 * i)  # fmt: skip
    TrainingJob.objects.filter(pk=job.pk).update(iterations=len(progress))


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
    model = services.model_create(owner=alice, name="ready", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False, stop_when_ready=3)  # fmt: skip
    job = services.training_start(model=model, user=alice, enqueue=False)
    record(job, [100.0, 40.0, 100.0, 100.0])
    config, job = started(monkeypatch, job)
    assert config.stop_when_ready == 3 and config.clean_streak == 2
    assert job.resumed_from.endswith("; ready streak 2 of 3 carried on")


def test_a_new_job_and_a_job_without_the_setting_start_from_nothing(alice, monkeypatch) -> None:
    model = services.model_create(owner=alice, name="ready", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False, stop_when_ready=3)  # fmt: skip
    first = services.training_start(model=model, user=alice, enqueue=False)
    record(first, [100.0, 100.0])
    # it failed after two clean evaluations; the model is trained again
    TrainingJob.objects.filter(pk=first.pk).update(status=JobStatus.FAILED)
    RacingModel.objects.filter(pk=model.pk).update(status=RacingModel.Status.ERROR)
    second = services.training_start(model=model, user=alice, enqueue=False)
    config, second = started(monkeypatch, second)
    assert config.clean_streak == 0 and "ready streak" not in second.resumed_from

    plain = services.model_create(owner=alice, name="plain", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False)  # fmt: skip
    job = services.training_start(model=plain, user=alice, enqueue=False)
    record(job, [100.0, 100.0])
    config, _ = started(monkeypatch, job)
    assert config.stop_when_ready == 0 and config.clean_streak == 0
