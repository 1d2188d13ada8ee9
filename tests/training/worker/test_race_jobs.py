"""Race jobs: a head-to-head race queued through Redis to a real Celery worker, run against
PostgreSQL and the store; its results, MP4 and per-car sim-traces; frozen league entries,
withdrawn and deleted models; who may race whose models; a race never left stuck. (Alice and
Bob race; Mallory tries to race their models.)"""

from __future__ import annotations

import time

import pytest
from django.contrib.auth import get_user_model
from django.utils import timezone

from tests.support import constant
from training import services
from training.errors import ServiceError
from training.interchange.layout import RaceKeys
from training.models import JobStatus, RaceJob
from training.services import race_plan
from training.services.races import race_start
from training.store import get_store, keys_for
from training.worker.race import run_race_job

SHORT = {"track_id": "racecraft_oval", "laps": 1, "time_limit_s": 10.0}


def crash_pair(racer_model):
    """Alice's car turns across the outer lane from pole; Bob's comes fast behind it."""
    return racer_model("alice", constant(-30, 0.5)), racer_model("bob", constant(5, 1.5))


def wait_for(race_id: int, within_s: float = 180.0) -> RaceJob:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        job = RaceJob.objects.get(pk=race_id)
        if job.status in (JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.CANCELED):
            return job
        time.sleep(0.5)
    pytest.fail(f"race {race_id} did not finish in {within_s:.0f} s")


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_a_race_runs_on_a_celery_worker_and_keeps_its_results_video_and_traces(
    racer_model, celery_worker, store_dir
):
    alice, bob = crash_pair(racer_model)
    staff = get_user_model().objects.create_user("steward", password="x-long-pass-1",
                                                 is_staff=True)  # fmt: skip
    plan = race_plan(model_ids=[alice.pk, bob.pk], **SHORT)
    job = race_start(plan=plan, user=staff, title="Heat 1")
    job = wait_for(job.pk)
    assert job.status == JobStatus.COMPLETED, job.error
    cars = {car["model"]: car for car in job.car_rows}
    assert set(cars) == {alice.pk, bob.pk} and cars[bob.pk]["crashes"] >= 1
    assert job.results["winner"] == job.car_rows[0]["model"]
    assert job.has_video and job.race_time_s == pytest.approx(10.0)
    keys, store = RaceKeys(job.pk), get_store()
    assert store.get_bytes(keys.video)[4:8] == b"ftyp"  # an MP4
    logs = pytest.importorskip("deepracer.logs")
    for model in (alice, bob):
        folder = store_dir / keys.car_folder(model.pk)
        log = logs.DeepRacerLog(model_folder=str(folder))
        log.load_evaluation_trace(force=True)
        assert len(log.dataframe()) > 0


@pytest.mark.django_db
def test_the_same_race_run_twice_gives_the_same_results(racer_model):
    alice, bob = crash_pair(racer_model)
    plan = race_plan(model_ids=[alice.pk, bob.pk], record_video=False, **SHORT)
    steward = get_user_model().objects.create_user("steward", is_staff=True)
    results = []
    for _ in range(2):
        job = race_start(plan=plan, user=steward, enqueue=False)
        assert run_race_job(job.pk, "test") == "completed"
        results.append(RaceJob.objects.get(pk=job.pk).results)
    assert results[0] == results[1] and results[0]["cars"]


@pytest.mark.django_db
def test_a_frozen_league_entry_races_after_its_model_is_deleted_and_a_withdrawn_one_is_out(
    racer_model,
):
    alice, bob = crash_pair(racer_model)
    carol = racer_model("carol", constant(0, 1.0))
    frozen = RaceKeys.frozen_checkpoint("event-1", alice.pk)
    store = get_store()
    store.put_bytes(frozen, store.get_bytes(keys_for(alice.pk).best))
    plan = race_plan(model_ids=[alice.pk, bob.pk, carol.pk], record_video=False, **SHORT)
    job = race_start(plan=plan, user=None, purpose="league", enqueue=False,
                     checkpoints={alice.pk: frozen})  # fmt: skip
    entries = job.entries
    assert entries[0]["metadata"] == services.model_metadata(alice).to_json()
    entries[2]["withdrawn"] = "its racer withdrew"
    RaceJob.objects.filter(pk=job.pk).update(entries=entries)
    alice_id = alice.pk
    services.model_delete(model=alice, user=alice.owner)
    assert run_race_job(job.pk, "test") == "completed"
    cars = {car["model"]: car for car in RaceJob.objects.get(pk=job.pk).car_rows}
    assert (cars[alice_id]["status"], cars[alice_id]["reason"]) == ("time_up", "")
    assert (cars[carol.pk]["status"], cars[carol.pk]["reason"]) == ("out", "its racer withdrew")


@pytest.mark.django_db
def test_a_deleted_model_without_a_frozen_copy_is_out_with_the_reason(racer_model):
    alice, bob = crash_pair(racer_model)
    plan = race_plan(model_ids=[alice.pk, bob.pk], record_video=False, **SHORT)
    job = race_start(plan=plan, user=get_user_model().objects.create_user("s", is_staff=True),
                     enqueue=False)  # fmt: skip
    bob_id = bob.pk
    services.model_delete(model=bob, user=bob.owner)
    assert run_race_job(job.pk, "test") == "completed"
    cars = {car["model"]: car for car in RaceJob.objects.get(pk=job.pk).car_rows}
    assert cars[bob_id]["reason"] == "its model was deleted"


@pytest.mark.django_db
def test_a_racer_races_only_their_own_models(racer_model):
    alice, bob = crash_pair(racer_model)
    alice2 = services.model_create(
        owner=alice.owner, name="second", track_id="racecraft_oval",
        action_space=constant(0, 1.0), validate_reward=False,
        reward_function="def reward_function(p):\n    return 1.0\n",
    )  # fmt: skip
    mallory = get_user_model().objects.create_user("mallory", password="x-long-pass-1")
    with pytest.raises(ServiceError, match="only your own models"):
        race_start(plan=race_plan(model_ids=[alice.pk, bob.pk], **SHORT), user=mallory,
                   enqueue=False)  # fmt: skip
    with pytest.raises(ServiceError, match="only your own models"):
        race_start(plan=race_plan(model_ids=[alice.pk, bob.pk], **SHORT), user=alice.owner,
                   enqueue=False)  # fmt: skip
    own = race_start(plan=race_plan(model_ids=[alice.pk, alice2.pk], **SHORT),
                     user=alice.owner, enqueue=False)  # fmt: skip
    assert own.owner == alice.owner and own.model_ids == [alice.pk, alice2.pk]


@pytest.mark.django_db
def test_a_race_on_a_track_that_cannot_be_had_fails_with_a_clear_message(racer_model):
    alice, bob = crash_pair(racer_model)
    plan = race_plan(model_ids=[alice.pk, bob.pk], record_video=False, **SHORT)
    job = race_start(plan=plan, user=get_user_model().objects.create_user("s", is_staff=True),
                     enqueue=False)  # fmt: skip
    RaceJob.objects.filter(pk=job.pk).update(track_id="gone_track")
    assert run_race_job(job.pk, "test") == "failed"
    job = RaceJob.objects.get(pk=job.pk)
    assert job.status == JobStatus.FAILED and "gone_track" in job.error


@pytest.mark.django_db
def test_the_reaper_queues_again_a_race_whose_worker_died(racer_model, monkeypatch):
    alice, bob = crash_pair(racer_model)
    plan = race_plan(model_ids=[alice.pk, bob.pk], **SHORT)
    job = race_start(plan=plan, user=get_user_model().objects.create_user("s", is_staff=True),
                     enqueue=False)  # fmt: skip
    sent = []
    monkeypatch.setattr("training.dispatch.send", lambda name, *args: sent.append(name) or "t1")
    long_ago = timezone.now() - timezone.timedelta(hours=1)
    RaceJob.objects.filter(pk=job.pk).update(status=JobStatus.IN_PROGRESS, worker="gone#1",
                                             heartbeat_at=long_ago, attempts=1)  # fmt: skip
    with django_capture_on_commit():
        assert services.jobs_reap_orphans() >= 1
    assert RaceJob.objects.get(pk=job.pk).status == JobStatus.QUEUED
    assert sent == ["training.tasks.evaluate_race"]


def django_capture_on_commit():
    """Run on-commit callbacks at once (the test's transaction never commits)."""
    from unittest import mock

    return mock.patch("django.db.transaction.on_commit", lambda fn, *a, **k: fn())
