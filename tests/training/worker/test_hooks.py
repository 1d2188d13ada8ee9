"""A training job's hooks record progress while an iteration runs, not only at its end."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model

from training import services
from training.models import JobStatus, TrainingJob
from training.worker import training as worker_training

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"


def test_finished_episodes_are_counted_while_the_iteration_runs(monkeypatch):
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    model = services.model_create(owner=alice, name="m1", track_id="racecraft_oval",
                                  action_space=ACTIONS, validate_reward=False,
                                  reward_function=REWARD)  # fmt: skip
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)
    hooks = worker_training.JobHooks(job)
    try:
        monkeypatch.setattr(worker_training, "EPISODE_COUNT_EVERY_S", 0.0)
        for episode in range(3):
            hooks.on_episode({"car": 0, "env_episode": episode})
        job.refresh_from_db()
        assert job.episodes == 3  # before any iteration has finished
        monkeypatch.setattr(worker_training, "EPISODE_COUNT_EVERY_S", 3600.0)
        hooks.on_episode({"car": 0, "env_episode": 3})
        job.refresh_from_db()
        assert job.episodes == 3  # at most one write per interval
    finally:
        hooks.close()


def test_a_resumed_job_logs_into_a_new_sim_trace_file():
    from training.models import EpisodeMetric

    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    model = services.model_create(owner=alice, name="m1", track_id="racecraft_oval",
                                  action_space=ACTIONS, validate_reward=False,
                                  reward_function=REWARD,
                                  hyperparameters={"num_episodes_between_training": 4})  # fmt: skip
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)
    # The earlier run logged one whole iteration (4 episodes) and one cut short (2).
    EpisodeMetric.objects.bulk_create(
        EpisodeMetric(job=job, iteration=1 + n // 4, episode=n + 1, phase="training",
                      reward_score=0, completion_percentage=0, episode_status="off_track",
                      elapsed_time_in_milliseconds=0, start_time=0, metric_time=0)
        for n in range(6)
    )  # fmt: skip
    hooks = worker_training.JobHooks(job)
    try:
        assert hooks.log.logged == 8  # numbering goes on at the third iteration (file 2)
    finally:
        hooks.close()
