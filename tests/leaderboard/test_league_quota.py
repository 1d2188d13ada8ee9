"""League work inside the job quota (issue 47): a racer's submission evaluations and the races
of the community events they organise count against ``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER``
beside their own jobs. Alice, with a quota of 2, organises three community races and tries to
get more than 2 jobs going through them; each refusal says why and loses nothing (a refused
submission is not counted, a refused turn stays in the queue, a held-back bracket match waits
and starts later). Bob and Charlie only enter: their quota is never spent by Alice's races.
Fran's public event is the league's own and is charged to nobody."""

from __future__ import annotations

import threading
from datetime import timedelta

import pytest
from django.db import connection
from django.utils import timezone
from league_helpers import finish_evaluation, lap, make_event, make_model, make_user

from leaderboard import bracket, events, raceday, racefinish
from leaderboard.access import LeagueError
from leaderboard.bracket import QUOTA_WAIT_NOTE, LeagueQuotaError
from leaderboard.models import BracketMatch, Event, RaceDaySlot, Submission
from leaderboard.services import submission_create
from training.models import ACTIVE_JOB_STATUSES, EvaluationJob, JobStatus, RaceJob, TrainingJob
from training.services import ServiceError, evaluation_start

pytestmark = pytest.mark.django_db


def active_jobs_of(user) -> int:
    """Every job charged to ``user`` that is queued or running, counted from the tables."""
    return (
        TrainingJob.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + EvaluationJob.objects.filter(model__owner=user, status__in=ACTIVE_JOB_STATUSES).count()
        + RaceJob.objects.filter(owner=user, status__in=ACTIVE_JOB_STATUSES).count()
    )


def community_race(organiser, name: str, **extra) -> Event:
    """A community race organised through the league's service (the organiser is entered)."""
    now = timezone.now()
    fields = {"name": name, "track_id": "racecraft_oval", "opens_at": now - timedelta(hours=1),
              "closes_at": now + timedelta(days=7), "ranking_method": "BEST_LAP",
              "min_laps": 1, "max_laps": 3, **extra}  # fmt: skip
    return events.event_create(organiser=organiser, is_private=True, **fields)


def ranked_entry(event: Event, racer, name: str, score_ms: int = 30_000) -> Submission:
    """A racer's ranked entry with its frozen weights, as an evaluated submission leaves it."""
    model = make_model(racer, name=name)
    return Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, ranked=True, score_ms=score_ms, best_lap_ms=score_ms,
        entered_model_id=model.pk, frozen_checkpoint=f"league/event-{event.pk}/{name}.zip",
        model_metadata={"action_space": model.action_space, "sensor": ["FRONT_FACING_CAMERA"]},
    )  # fmt: skip


@pytest.fixture
def quota_of_two(settings):
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 2


def test_a_racer_is_held_to_their_quota_through_submissions_events_and_race_days(
    quota_of_two, alice, bob, charlie
):
    races = [community_race(alice, f"Alice's cup {i}") for i in range(3)]
    for event in races:  # Bob and Charlie entered each one; their entries wait to race
        raceday.race_day_add(
            event=event, user=alice, submission=ranked_entry(event, bob, f"b{event.pk}")
        )
        raceday.race_day_add(event=event, user=alice,
                             submission=ranked_entry(event, charlie, f"c{event.pk}"))  # fmt: skip

    # Submissions: two evaluations go, the third is refused and not counted.
    subs = [submission_create(event=races[i], user=alice, model=make_model(alice, f"a{i}"))
            for i in range(2)]  # fmt: skip
    assert active_jobs_of(alice) == 2
    with pytest.raises(LeagueError, match="2 jobs queued or running.*not used") as refused:
        submission_create(event=races[2], user=alice, model=make_model(alice, "a2"))
    assert refused.value.field == "model"
    assert not Submission.objects.filter(event=races[2], racer=alice).exists()
    assert EvaluationJob.objects.filter(model__owner=alice).count() == 2
    with pytest.raises(ServiceError, match="2 jobs queued or running"):  # nor her own work
        evaluation_start(model=make_model(alice, "own"), user=alice)

    # Race days: a turn of her own event is her job too; refused, it stays first in line.
    with pytest.raises(LeagueQuotaError, match="organiser already has 2 queued or running"):
        raceday.race_day_launch(event=races[0], user=alice)
    assert RaceJob.objects.count() == 0
    assert list(RaceDaySlot.objects.filter(event=races[0]).values_list("status", flat=True)) == [
        RaceDaySlot.Status.WAITING, RaceDaySlot.Status.WAITING]  # fmt: skip

    # One evaluation ends: one turn launches (charged to Alice), the next is refused.
    finish_evaluation(subs[0].evaluation, [lap(31.0)])
    first = raceday.race_day_launch(event=races[0], user=alice)
    assert first.race.owner == alice and active_jobs_of(alice) == 2
    for event in races[1:]:
        with pytest.raises(LeagueQuotaError):
            raceday.race_day_launch(event=event, user=alice)
    # The third submission goes once a job has finished, and counts again.
    finish_evaluation(subs[1].evaluation, [lap(32.0)])
    submission_create(event=races[2], user=alice, model=make_model(alice, "a2-again"))
    with pytest.raises(LeagueQuotaError):
        raceday.race_day_launch(event=races[1], user=alice)
    assert active_jobs_of(alice) == 2  # never more, whatever she tried

    # The entrants' quota is untouched by the organiser's races: Bob still evaluates twice.
    for i in range(2):
        evaluation_start(model=make_model(bob, f"bob-own-{i}"), user=bob)
    assert active_jobs_of(bob) == 2 and RaceJob.objects.filter(owner=bob).count() == 0


def test_a_bracket_held_back_by_the_quota_waits_and_starts_when_a_job_finishes(quota_of_two, alice):
    event = community_race(alice, "Alice's knockout", race_type="HEAD_TO_BOT", bot_count=2,
                           bot_speed_mps=0.75, ranking_method="TOTAL_TIME", bracket_size=8,
                           bracket_laps=2)  # fmt: skip
    for i in range(8):  # eight qualifiers: four first-round matches
        ranked_entry(event, make_user(f"racer{i}", alias=f"Racer-{i}"), f"q{i}",
                     score_ms=30_000 + 100 * i)  # fmt: skip
    own = evaluation_start(model=make_model(alice, "own"), user=alice)  # one job of her own
    bracket.bracket_seed(event=event, user=alice)
    matches = BracketMatch.objects.filter(event=event, round=1)
    assert matches.count() == 4
    assert matches.filter(race__isnull=False).count() == 1 and active_jobs_of(alice) == 2
    waiting = matches.filter(race__isnull=True)
    assert waiting.count() == 3 and set(waiting.values_list("note", flat=True)) == {QUOTA_WAIT_NOTE}
    assert not matches.filter(winner__isnull=False).exists()  # held back, never decided

    # Its race ends: the winner goes through and a waiting match starts in its place.
    race = matches.get(race__isnull=False).race
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED,
                                              results={"winner": None, "cars": []})  # fmt: skip
    bracket.bracket_race_finished(race_id=race.pk)
    assert matches.filter(winner__isnull=False).count() == 1
    assert matches.filter(race__isnull=False).count() == 2 and active_jobs_of(alice) == 2

    # Her own evaluation ends (no bracket signal): the minute's reconcile starts the next one.
    finish_evaluation(own, [lap(30.0)])
    assert racefinish.races_reconcile() == 1
    assert matches.filter(race__isnull=False).count() == 3 and active_jobs_of(alice) == 2
    started = matches.filter(race__isnull=False, winner__isnull=True)
    assert list(started.values_list("note", flat=True)) == ["", ""]  # the wait note cleared
    assert racefinish.races_reconcile() == 0  # full again: the last match still waits
    assert matches.get(race__isnull=True).note == QUOTA_WAIT_NOTE


def test_a_public_events_races_are_the_leagues_and_charge_nobody(quota_of_two, fran, bob):
    event = make_event(fran)
    raceday.race_day_add(event=event, user=fran, submission=ranked_entry(event, bob, "pub"))
    for i in range(2):
        evaluation_start(model=make_model(fran, f"fran-own-{i}"), user=fran)
    slot = raceday.race_day_launch(event=event, user=fran)  # Fran's own quota is full
    assert slot.race.owner is None and active_jobs_of(fran) == 2


def test_the_web_page_says_why_a_turn_and_a_submission_were_refused(client, quota_of_two, alice,
                                                                     bob):  # fmt: skip
    event = community_race(alice, "Alice's evening race")
    raceday.race_day_add(event=event, user=alice, submission=ranked_entry(event, bob, "b1"))
    for i in range(2):
        evaluation_start(model=make_model(alice, f"own-{i}"), user=alice)
    client.force_login(alice)
    page = client.post(f"/league/events/{event.pk}/race-day/", {"action": "launch"}, follow=True)
    text = page.content.decode()
    assert "count against its organiser" in text and "nothing was started" in text
    assert 'data-testid="quota-note"' in text  # the race-day page says so before it happens
    assert RaceDaySlot.objects.get(event=event).status == RaceDaySlot.Status.WAITING
    model = make_model(alice, "entry")
    page = client.post(f"/league/events/{event.pk}/submit/", {"model": model.pk}, follow=True)
    assert "this submission was not used" in page.content.decode()
    assert not Submission.objects.filter(event=event, racer=alice).exists()


@pytest.mark.django_db(transaction=True)
def test_league_work_started_at_once_from_three_places_gets_one_job(settings, alice, bob):
    """A turn in each of two community races and a submission, all at the same instant, with
    one job left: exactly one starts (the organiser's row is locked while the quota is
    counted). Meaningful on PostgreSQL (row locks); SQLite serialises writers."""
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 1
    races = [community_race(alice, f"Alice's sprint {i}") for i in range(2)]
    for event in races:
        entry = ranked_entry(event, bob, f"b{event.pk}")
        raceday.race_day_add(event=event, user=alice, submission=entry)
    model = make_model(alice, "entry")
    barrier = threading.Barrier(3)
    outcomes: list[str] = []

    def attempt(start) -> None:
        try:
            barrier.wait(timeout=30)
            start()
            outcomes.append("started")
        except LeagueError as exc:
            outcomes.append(exc.message)
        except Exception as exc:  # noqa: BLE001 - a deadlock or any other error fails the test
            outcomes.append(f"crashed: {exc!r}")
        finally:
            connection.close()

    starts = [lambda e=event: raceday.race_day_launch(event=e, user=alice) for event in races]
    starts.append(lambda: submission_create(event=races[0], user=alice, model=model))
    threads = [threading.Thread(target=attempt, args=(start,)) for start in starts]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert len(outcomes) == 3 and outcomes.count("started") == 1, outcomes
    assert all("1 jobs queued or running" in o or "already has 1" in o
               for o in outcomes if o != "started"), outcomes  # fmt: skip
    assert active_jobs_of(alice) == 1
