"""Nothing lost, nothing stuck (issue #15), at the level of the job state machine: a training
job resumes from its last checkpoint and keeps its best one, a job whose worker process died
is taken over, a job whose task the broker lost is sent again, and a user's job cap holds when
two starts race each other."""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest
from django.contrib.auth import get_user_model
from django.db import connection
from django.utils import timezone

from training import dispatch, services
from training.models import IterationMetric, JobStatus, RacingModel, TrainingJob
from training.rl import runner
from training.rl.runner import EvaluationOutcome, TrainingConfig, TrainingHooks
from training.rollout.envs import EnvSpec
from training.rollout.experience import Experience
from training.services import ServiceError
from training.store import get_store, keys_for
from training.worker.training import _initial_checkpoint

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"


@pytest.fixture(autouse=True)
def store_dir(tmp_path, settings):
    settings.STORE_DIR = tmp_path / "store"


def _user(name: str):
    return get_user_model().objects.create_user(name, password=f"pw-{name}-123")


def _model(owner, name: str = "m1") -> RacingModel:
    return services.model_create(owner=owner, name=name, track_id="racecraft_oval",
                                 action_space=ACTIONS, reward_function=REWARD,
                                 validate_reward=False)  # fmt: skip


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ------------------------------------------------------------------------------ resuming
@pytest.mark.django_db
def test_a_failed_model_trained_again_resumes_from_its_last_checkpoint():
    alice = _user("alice")
    model = _model(alice)
    store, keys = get_store(), keys_for(model.pk)
    store.put_bytes(keys.last, b"LAST")
    store.put_bytes(keys.best, b"BEST")
    failed = TrainingJob.objects.create(
        model=model, max_minutes=5, status=JobStatus.FAILED, iterations=7, best_iteration=4,
        best_eval_progress=43.25, started_at=timezone.now(),
    )  # fmt: skip
    model.has_checkpoint = True
    model.status = RacingModel.Status.ERROR
    model.save()
    job = services.training_start(model=model, user=alice, enqueue=False)
    checkpoint, best, words, streak = _initial_checkpoint(job, model)
    assert checkpoint == b"LAST" and best == pytest.approx(43.25) and streak == 0
    assert f"job #{failed.pk}'s last checkpoint (iteration 7)" in words
    assert "best so far 43.2% evaluation progress" in words and "kept unless beaten" in words


@pytest.mark.django_db
def test_new_and_cloned_models_say_where_they_start():
    alice = _user("alice")
    fresh = _model(alice)
    job = services.training_start(model=fresh, user=alice, enqueue=False)
    assert _initial_checkpoint(job, fresh) == (None, None, "started from a new network", 0)
    get_store().put_bytes(keys_for(fresh.pk).best, b"PARENT")
    fresh.has_checkpoint = True
    fresh.save()
    TrainingJob.objects.filter(pk=job.pk).update(status=JobStatus.COMPLETED, iterations=2)
    clone = services.model_clone(model=fresh, owner=alice, name="c1")
    job = services.training_start(model=clone, user=alice, enqueue=False)
    checkpoint, best, words, streak = _initial_checkpoint(job, clone)
    assert checkpoint == b"PARENT" and best is None and streak == 0
    assert words == f"started from the checkpoint of model #{fresh.pk}"


class _Recorder(TrainingHooks):
    def __init__(self, stop_after: int) -> None:
        self.results, self.stop_after = [], stop_after

    def should_stop(self) -> bool:
        return len(self.results) >= self.stop_after

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)


@pytest.mark.parametrize("best_score, expected", [(None, [True, True, False]),
                                                  (45.0, [False, True, False])])  # fmt: skip
def test_the_runner_keeps_the_best_so_far_unless_beaten(monkeypatch, best_score, expected):
    """Iterations evaluate at 30%, 50%, 40%: with no best so far the first one is "best";
    resumed with a best of 45%, only the 50% iteration replaces it."""
    scores = iter([30.0, 50.0, 40.0])

    class Scripted:
        """Gathers one step a time and evaluates each policy at the next score."""

        env = None

        def gather(self, learner) -> Experience:
            learner.model.num_timesteps += 1
            return Experience(steps=1, episodes=[], rows=[], rollout_s=0.0)

        def evaluate(self, learner, iteration: int) -> None:
            learner.evaluated(iteration, EvaluationOutcome([next(scores)], ["off_track"], [[]],
                                                           [0.0]), 0.0)  # fmt: skip

        def finish(self, learner) -> None:
            pass

        def close(self) -> None:
            pass

    class Model:
        num_timesteps = 0

        def train(self) -> None:
            pass

        def set_logger(self, logger) -> None:
            pass

        def save(self, buffer) -> None:
            buffer.write(b"ckpt")

    class Backend:
        def experience(self, request):
            return Scripted()

    monkeypatch.setattr(runner, "build_model", lambda *args, **kwargs: Model())
    hooks = _Recorder(stop_after=3)
    config = TrainingConfig(spec=EnvSpec(track="racecraft_oval"), best_score=best_score,
                            rollouts=Backend())  # fmt: skip
    summary = runner.train(config, hooks)
    assert [r.best for r in hooks.results] == expected
    assert summary.best_eval_progress == 50.0


# ------------------------------------------------------------------------------ claims
@pytest.mark.django_db
def test_a_redelivered_task_takes_over_a_job_whose_worker_process_died():
    alice = _user("alice")
    model = _model(alice)
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS,
                                     worker=f"node@host#{_dead_pid()}", attempts=1,
                                     heartbeat_at=timezone.now())  # fmt: skip
    IterationMetric.objects.create(job=job, iteration=1, episodes=1, steps=1, total_steps=1,
                                   train_reward=0, train_progress=0, eval_progress=0,
                                   elapsed_s=120.0)  # fmt: skip
    # Another node cannot tell whether the process lives: it leaves the job alone.
    assert services.job_claim(job_model=TrainingJob, job_id=job.pk, worker="other@host") is None
    taken = services.job_claim(job_model=TrainingJob, job_id=job.pk, worker="node@host")
    assert taken is not None and taken.status == JobStatus.INITIALIZING and taken.attempts == 2
    assert taken.worker.startswith("node@host#")
    # The page's clock counts the two minutes already trained.
    assert 115 < (timezone.now() - taken.started_at).total_seconds() < 200
    # A second copy of the task finds the job held by a live process.
    assert services.job_claim(job_model=TrainingJob, job_id=job.pk, worker="node@host") is None


@pytest.mark.django_db
def test_a_live_worker_keeps_its_job_and_a_cut_off_one_cannot_end_the_new_run():
    alice = _user("alice")
    model = _model(alice)
    job = TrainingJob.objects.create(
        model=model, max_minutes=5, status=JobStatus.IN_PROGRESS, worker="node@host#1", attempts=1
    )  # pid 1 lives
    assert services.job_claim(job_model=TrainingJob, job_id=job.pk, worker="node@host") is None
    old_runner = TrainingJob.objects.get(pk=job.pk)
    # The job was queued again and claimed elsewhere while the old runner was cut off.
    TrainingJob.objects.filter(pk=job.pk).update(status=JobStatus.QUEUED, worker="")
    new_runner = services.job_claim(job_model=TrainingJob, job_id=job.pk, worker="b@host")
    assert services.job_stop_requested(job=old_runner)  # the old one stops...
    assert not services.job_fail(job=old_runner, error="cut off")  # ...and cannot end it
    assert not services.job_stop_requested(job=new_runner)
    assert TrainingJob.objects.get(pk=job.pk).status == JobStatus.INITIALIZING


# ------------------------------------------------------------------------------ lost tasks
def _purge_job_queues(redis_url: str) -> None:
    """Drop the job queues' messages, as a Redis restart that kept nothing would."""
    import redis
    from django.conf import settings

    client = redis.Redis.from_url(redis_url)
    try:
        for queue in dispatch.JOB_QUEUES:
            client.delete(f"{settings.REDIS_PREFIX}{queue}")
    finally:
        client.close()


@pytest.mark.django_db(transaction=True)
def test_the_reaper_sends_again_a_queued_job_whose_task_the_broker_lost(redis_url):
    alice = _user("alice")
    model = _model(alice)
    job = services.training_start(model=model, user=alice)  # queued on the test Redis
    job.refresh_from_db()
    assert job.task_id
    old = timezone.now() - timezone.timedelta(minutes=5)
    TrainingJob.objects.filter(pk=job.pk).update(created_at=old)
    try:
        present = dispatch.queued_task_ids()
        assert present is not None and job.task_id in present
        assert services.jobs_reap_orphans() == 0  # its task is there: nothing to do
        _purge_job_queues(redis_url)
        assert job.task_id not in dispatch.queued_task_ids()
        assert services.jobs_reap_orphans() == 1
        again = TrainingJob.objects.get(pk=job.pk)
        assert again.status == JobStatus.QUEUED and again.task_id != job.task_id
        assert again.task_id in dispatch.queued_task_ids()
        # Sent once: a second round within the grace period sends nothing more.
        TrainingJob.objects.filter(pk=job.pk).update(task_id="")
        assert services.jobs_reap_orphans() == 0
    finally:
        _purge_job_queues(redis_url)


# ------------------------------------------------------------------------------ quotas
@pytest.mark.django_db(transaction=True)
def test_two_starts_at_once_respect_the_job_cap(settings):
    """Two threads (two clicks, two tabs) start the user's last allowed job at the same time:
    exactly one succeeds. Meaningful on PostgreSQL (row locks); SQLite serialises writers."""
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 1
    alice = _user("alice")
    models = [_model(alice, "a"), _model(alice, "b")]
    barrier = threading.Barrier(2)
    outcomes: list[str] = []

    def start(model: RacingModel) -> None:
        try:
            barrier.wait(timeout=30)
            services.training_start(model=model, user=alice, enqueue=False)
            outcomes.append("started")
        except ServiceError as exc:
            outcomes.append(str(exc))
        finally:
            connection.close()

    for _ in range(3):
        TrainingJob.objects.all().delete()
        RacingModel.objects.update(status=RacingModel.Status.READY)
        outcomes.clear()
        threads = [threading.Thread(target=start, args=(m,)) for m in models]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
        assert sorted(outcomes)[0] == "started" and outcomes.count("started") == 1, outcomes
        assert TrainingJob.objects.filter(status=JobStatus.QUEUED).count() == 1
