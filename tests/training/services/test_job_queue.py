"""Fair dispatch (training.services.job_queue): a delivered task runs the fairest queued job of
its kind and swaps task ids with it, so every queued job keeps a task in the broker."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.utils import timezone

from training import services
from training.models import EvaluationJob, JobStatus, RaceJob, TrainingJob
from training.services.job_queue import fair_order

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-20, 0, 20)]
REWARD = "def reward_function(params):\n    return 1.0\n"

pytestmark = pytest.mark.django_db


def _user(name: str):
    return get_user_model().objects.create_user(name, password=f"pw-{name}-123")


def _queue(owner, n: int, *, at: float) -> list[TrainingJob]:
    """``n`` queued training jobs of ``owner``, created ``at`` seconds after a fixed start."""
    jobs = []
    for i in range(n):
        model = services.model_create(owner=owner, name=f"m{at:.0f}-{i}", track_id="racecraft_oval",
                                      action_space=ACTIONS, reward_function=REWARD,
                                      validate_reward=False)  # fmt: skip
        created = START + timezone.timedelta(seconds=at + i * 0.1)
        jobs.append(TrainingJob.objects.create(model=model, max_minutes=5, created_at=created,
                                               task_id=f"t-{owner.username}-{at}-{i}"))  # fmt: skip
    return jobs


START = timezone.now() - timezone.timedelta(hours=1)


def _claim(token_job: TrainingJob, worker: str = "w@host") -> TrainingJob | None:
    token = TrainingJob.objects.get(pk=token_job.pk).task_id
    return services.job_claim(job_model=TrainingJob, job_id=token_job.pk, worker=worker,
                              task_id=token)  # fmt: skip


def _finish(job: TrainingJob) -> None:
    TrainingJob.objects.filter(pk=job.pk).update(status=JobStatus.COMPLETED,
                                                 finished_at=timezone.now())  # fmt: skip


def test_one_users_burst_does_not_hold_the_others_back():
    alice, bob, carol = _user("alice"), _user("bob"), _user("carol")
    a = _queue(alice, 4, at=0)  # Alice queued four jobs first,
    b = _queue(bob, 1, at=10)  # then Bob and Carol one each.
    c = _queue(carol, 1, at=20)
    order = fair_order(TrainingJob)
    assert order[:3] == [a[0].pk, b[0].pk, c[0].pk]
    assert order[3:] == [j.pk for j in a[1:]]

    # Alice's tasks are delivered first (they were sent first): the slots still run one job
    # of each user before Alice's second, and the tokens move to the jobs left waiting.
    started = []
    for token_job in a[:3]:
        job = _claim(token_job)
        started.append(job.pk)
        _finish(job)
    assert started == [a[0].pk, b[0].pk, c[0].pk]
    waiting = TrainingJob.objects.filter(status=JobStatus.QUEUED)
    assert sorted(waiting.values_list("pk", flat=True)) == [j.pk for j in a[1:]]
    tokens = set(waiting.values_list("task_id", flat=True))
    # Each waiting job holds a token still in the broker: Alice's fourth, Bob's and Carol's.
    assert tokens == {a[3].task_id, b[0].task_id, c[0].task_id}
    claimed = TrainingJob.objects.exclude(status=JobStatus.QUEUED)
    assert set(claimed.values_list("task_id", flat=True)) == {j.task_id for j in a[:3]}


def test_turns_count_only_while_the_user_waits():
    alice, bob = _user("alice"), _user("bob")
    old = _queue(alice, 2, at=0)
    for job in old:  # Alice's earlier jobs ran before anyone was waiting
        TrainingJob.objects.filter(pk=job.pk).update(
            status=JobStatus.COMPLETED, started_at=job.created_at + timezone.timedelta(seconds=1)
        )
    later = _queue(alice, 1, at=100)
    bob_job = _queue(bob, 1, at=200)
    # Neither has had a turn while waiting: first come, first served.
    assert fair_order(TrainingJob) == [later[0].pk, bob_job[0].pk]
    # A user who holds a slot now waits behind one who holds none, turns being equal.
    TrainingJob.objects.filter(pk=old[1].pk).update(status=JobStatus.IN_PROGRESS)
    assert fair_order(TrainingJob) == [bob_job[0].pk, later[0].pk]


def test_concurrent_slots_never_claim_one_job_twice_and_spare_tasks_run_the_next():
    alice, bob = _user("alice"), _user("bob")
    a = _queue(alice, 2, at=0)
    b = _queue(bob, 1, at=10)
    first = _claim(a[0], worker="w1@host")
    assert first.pk == a[0].pk
    # The same task delivered twice (a duplicate): the copy is a spare and runs the next job.
    again = services.job_claim(job_model=TrainingJob, job_id=a[0].pk, worker="w2@host",
                               task_id=first.task_id)  # fmt: skip
    assert again is not None and again.pk == b[0].pk
    assert TrainingJob.objects.get(pk=a[0].pk).status == JobStatus.INITIALIZING
    # A canceled job's task is a spare too.
    TrainingJob.objects.filter(pk=a[1].pk).update(status=JobStatus.CANCELED)
    assert services.job_claim(job_model=TrainingJob, job_id=a[1].pk, worker="w3@host",
                              task_id=a[1].task_id) is None  # fmt: skip


def test_the_command_line_runs_its_own_job_whatever_waits_before_it():
    alice, bob = _user("alice"), _user("bob")
    _queue(alice, 1, at=0)
    mine = _queue(bob, 1, at=10)[0]
    taken = services.job_claim(job_model=TrainingJob, job_id=mine.pk, worker="cli@host")
    assert taken.pk == mine.pk


def test_evaluations_are_fair_and_a_lone_race_runs_on_its_own_token():
    alice, bob = _user("alice"), _user("bob")
    models = {}
    for user, n in ((alice, 2), (bob, 1)):
        for i in range(n):
            model = services.model_create(owner=user, name=f"e{i}", track_id="racecraft_oval",
                                          action_space=ACTIONS, reward_function=REWARD,
                                          validate_reward=False)  # fmt: skip
            models[(user.username, i)] = model
    e = [EvaluationJob.objects.create(model=models[key], track_id="racecraft_oval",
                                      task_id=f"e-{n}",
                                      created_at=START + timezone.timedelta(seconds=n))
         for n, key in enumerate([("alice", 0), ("alice", 1), ("bob", 0)])]  # fmt: skip
    EvaluationJob.objects.filter(pk=e[0].pk).update(status=JobStatus.IN_PROGRESS,
                                                    started_at=timezone.now())  # fmt: skip
    taken = services.job_claim(job_model=EvaluationJob, job_id=e[1].pk, worker="w@host",
                               task_id="e-1")  # fmt: skip
    assert taken.pk == e[2].pk and EvaluationJob.objects.get(pk=e[1].pk).task_id == "e-2"
    race = RaceJob.objects.create(task_id="r-1")
    claimed = services.job_claim(job_model=RaceJob, job_id=race.pk, worker="w@host",
                                 task_id="r-1")  # fmt: skip
    assert claimed.pk == race.pk


def test_a_waiting_owner_sees_how_many_jobs_run_before_theirs(client):
    alice, bob = _user("alice"), _user("bob")
    a = _queue(alice, 3, at=0)
    b = _queue(bob, 1, at=10)
    assert [services.jobs_ahead(j) for j in a] == [0, 2, 3]
    assert services.jobs_ahead(b[0]) == 1
    client.force_login(bob)
    page = client.get(f"/models/{b[0].model_id}/").content.decode()
    assert "1 job ahead" in page
    TrainingJob.objects.filter(pk=a[0].pk).update(status=JobStatus.IN_PROGRESS)
    assert services.jobs_ahead(TrainingJob.objects.get(pk=a[0].pk)) is None
    assert "next to start" in client.get(f"/models/{b[0].model_id}/").content.decode()
