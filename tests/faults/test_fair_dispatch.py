"""Fair dispatch under load (issue 25), through real Celery workers, Redis and PostgreSQL: 20
users queue 40 training jobs at once on 2 worker slots, the heaviest users first (DeepRacer-on-
AWS's issue #87: with ~38 jobs queued, users' jobs waited while capacity sat idle).

Each job's body is a stand-in that holds its slot for ``JOB_S`` seconds
(tests/faults/standin_jobs.py); what is tested is everything around it: the quota, the tasks
in the broker, the slot that takes a task running the fairest job and swapping tokens, and the
completion. ``pytest -s`` prints the figures docs/operator.md quotes."""

from __future__ import annotations

import itertools
import statistics
from collections import defaultdict
from contextlib import ExitStack

import pytest
from django.contrib.auth import get_user_model
from django.db import transaction

from tests.faults.workers import celery_worker, wait_for
from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from training import services
from training.models import JobStatus, TrainingJob

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow, pytest.mark.timeout(900)]
JOB_S = 0.4
SLOTS = 2
JOBS_PER_USER = [5] * 4 + [2] * 4 + [1] * 12  # 20 users, 40 jobs
GAP_BOUND_S = 10.0
"""A slot's longest pause between one job's end and its next start while jobs waited (about
0.05 s on a quiet machine; the bound only catches a slot left idle)."""


def test_forty_jobs_of_twenty_users_on_two_slots(settings, redis_env, tmp_path, store_dir):
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 5
    users, models = [], []
    for i, count in enumerate(JOBS_PER_USER):
        user = get_user_model().objects.create_user(f"racer{i:02d}", password="pw-racer-123")
        users.append(user)
        for k in range(count):
            model = services.model_create(owner=user, name=f"m{k}", track_id="racecraft_oval",
                                          action_space=ACTIONS, reward_function=REWARD,
                                          validate_reward=False)  # fmt: skip
            models.append((user, model))
    spare = services.model_create(owner=users[0], name="sixth", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False)  # fmt: skip

    env = {**redis_env, "STORE_DIR": str(store_dir), "STANDIN_JOB_S": str(JOB_S)}
    logs = [tmp_path / f"slot{n}.log" for n in range(SLOTS)]
    with ExitStack() as stack:
        for n, log in enumerate(logs):
            stack.enter_context(celery_worker(log, env, queues="training", name=f"slot{n}@%h",
                                              app="tests.faults.standin_jobs"))  # fmt: skip
        # Everyone queues at once (one commit; the tasks are sent after it), heaviest first.
        with transaction.atomic():
            jobs = [services.training_start(model=model, user=user) for user, model in models]
            # The quota holds: a sixth job of a user with five queued is refused.
            with pytest.raises(services.ServiceError, match="5 jobs queued or running"):
                services.training_start(model=spare, user=users[0])

        def all_done() -> bool:
            done = TrainingJob.objects.filter(status=JobStatus.COMPLETED).count()
            return done == len(jobs)

        wait_for(all_done, 300, "all 40 jobs to complete", logs[0])

    rows = list(TrainingJob.objects.filter(pk__in=[j.pk for j in jobs]).select_related("model"))
    assert all(r.attempts == 1 and r.started_at and r.finished_at for r in rows)
    by_user: dict[int, list[TrainingJob]] = defaultdict(list)
    for r in sorted(rows, key=lambda r: r.started_at):
        by_user[r.model.owner_id].append(r)
    assert len(by_user) == 20

    # Each user's first job starts before any user's third (and every second before any
    # fourth): rounds, although the heavy users' tasks were sent first.
    for k in (0, 1):
        last_kth = max(js[k].started_at for js in by_user.values() if len(js) > k)
        first_later = min(js[k + 2].started_at for js in by_user.values() if len(js) > k + 2)
        assert last_kth < first_later, f"a job {k + 3} started before every job {k + 1}"

    # No slot idles while a job waits: both slots ran jobs, and each took its next job
    # straight after the last (every job was waiting from the commit to the last start).
    by_slot: dict[str, list[TrainingJob]] = defaultdict(list)
    for r in sorted(rows, key=lambda r: r.started_at):
        by_slot[r.worker].append(r)
    assert len(by_slot) == SLOTS, sorted(by_slot)
    pairs = [pair for slot in by_slot.values() for pair in itertools.pairwise(slot)]
    gaps = [(b.started_at - a.finished_at).total_seconds() for a, b in pairs]
    assert max(gaps) < GAP_BOUND_S, gaps
    assert all(a.finished_at <= b.started_at for a, b in pairs)  # one job at a time a slot

    queued_at = max(r.created_at for r in rows)  # the commit came right after the last
    makespan = (max(r.finished_at for r in rows) - queued_at).total_seconds()
    first_waits = [(js[0].started_at - queued_at).total_seconds() for js in by_user.values()]
    ideal = len(rows) * JOB_S / SLOTS
    print(
        f"\nfair dispatch: {len(rows)} jobs of {len(by_user)} users on {SLOTS} slots, "
        f"{JOB_S} s each\n"
        f"  makespan {makespan:.1f} s (ideal {ideal:.1f} s), slot gap median "
        f"{statistics.median(gaps) * 1000:.0f} ms, max {max(gaps) * 1000:.0f} ms\n"
        f"  a user's first job waited: median {statistics.median(first_waits):.1f} s, "
        f"longest {max(first_waits):.1f} s; jobs per slot "
        f"{sorted(len(s) for s in by_slot.values())}"
    )
