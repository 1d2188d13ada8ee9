"""Issue 48's loose end: Alice stops her race before any worker claimed it. A queued race is
canceled at once (it never runs, her job quota share is free again, its frozen checkpoints
go); a race a worker has claimed stops at its next step, as before
(tests/console/test_races_views.py)."""

from __future__ import annotations

import pytest

from tests.console.test_races_views import field, form, logged_in  # noqa: F401 - a fixture
from training.models import JobStatus, RaceJob
from training.services import challenges
from training.services.job_runs import job_claim
from training.services.race_control import race_stop
from training.signals import race_finished
from training.store import get_store

pytestmark = pytest.mark.django_db


def test_a_queued_race_is_canceled_at_once_and_gives_its_quota_back(
    field,  # noqa: F811 - the fixture imported above
    alice,
    settings,
    django_capture_on_commit_callbacks,
):
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 1
    alice_car, bob_open, _ = field
    a = logged_in(alice)
    assert a.post("/races/new/", form(alice_car, bob_open)).status_code == 302
    race = RaceJob.objects.get()
    frozen = f"league/race-{race.pk}/"
    assert get_store().list(frozen)  # each car's frozen checkpoint
    assert a.post("/races/new/", form(alice_car, bob_open)).status_code == 400  # quota full

    ended: list[int] = []

    def heard(sender, race_id: int, **kwargs) -> None:
        ended.append(race_id)

    race_finished.connect(heard)
    try:
        with django_capture_on_commit_callbacks(execute=True):
            response = a.post(f"/races/{race.pk}/stop/", follow=True)
    finally:
        race_finished.disconnect(heard)
    assert "Race canceled before it started" in response.content.decode()
    race.refresh_from_db()
    assert race.status == JobStatus.CANCELED and race.stop_requested
    assert race.finished_at is not None and race.started_at is None
    assert ended == [race.pk]  # the league hears of it as of any race that ended
    assert not get_store().list(frozen)  # no car will race the frozen copies
    # It never runs: a worker that gets its task finds nothing to claim.
    assert job_claim(job_model=RaceJob, job_id=race.pk, worker="w1@test") is None
    page = a.get(f"/races/{race.pk}/").content.decode()
    assert 'id="race-canceled"' in page and 'id="stop-race"' not in page
    # The quota share is back: Alice races again.
    assert a.post("/races/new/", form(alice_car, bob_open)).status_code == 302
    assert RaceJob.objects.count() == 2
    # A second stop of the canceled race changes nothing.
    response = a.post(f"/races/{race.pk}/stop/", follow=True)
    assert "already ended" in response.content.decode()


def test_a_claimed_race_is_asked_to_stop_and_keeps_running_until_its_worker_stops(
    field,  # noqa: F811 - the fixture imported above
    alice,
):
    alice_car, bob_open, _ = field
    logged_in(alice).post("/races/new/", form(alice_car, bob_open))
    race = RaceJob.objects.get()
    for status in (JobStatus.INITIALIZING, JobStatus.IN_PROGRESS):
        RaceJob.objects.filter(pk=race.pk).update(status=status, stop_requested=False)
        race.refresh_from_db()
        assert challenges.challenge_stop(race=race, by="alice") == challenges.STOPPING
        race.refresh_from_db()
        assert race.status == status and race.stop_requested  # the worker polls the flag
        assert get_store().list(f"league/race-{race.pk}/")  # still racing its copies
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED)
    race.refresh_from_db()
    assert race_stop(race=race, by="alice") is False
    assert challenges.challenge_stop(race=race, by="alice") == challenges.ENDED
