"""The race code's rooms (leaderboard/racefinish.py, bracket.py, raceday.py): one receiver of
training's ``race_finished`` decides whose race it was, so a finished race moves the race day
or the bracket as it belongs; the bracket's results live in its match rows only (the event
keeps the seeding); the migration that moved them loses nothing. Fran runs the events."""

from __future__ import annotations

import importlib

import pytest
from django.apps import apps as django_apps
from league_helpers import make_event, make_model, make_user

from leaderboard import bracket, raceday
from leaderboard.bracket_draw import champion, record_winner, seed_bracket
from leaderboard.models import BracketMatch, RaceDaySlot, Submission
from leaderboard.racefinish import BRACKET, RACE_DAY, league_race_finished
from leaderboard.selectors import bracket_state
from training.models import JobStatus, RaceJob
from training.signals import race_finished

pytestmark = pytest.mark.django_db


def ranked(event, name: str, score_ms: int) -> Submission:
    racer = make_user(name, alias=name.title())
    model = make_model(racer, name=f"{name}-car")
    return Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, ranked=True, score_ms=score_ms,
        entered_model_id=model.pk, frozen_checkpoint=f"league/event-{event.pk}/{name}.zip",
        model_metadata={"action_space": model.action_space, "sensor": ["FRONT_FACING_CAMERA"]},
    )  # fmt: skip


def won_by(race: RaceJob, sub: Submission | None) -> None:
    """The race ends as the worker ends it, and training says so (the one signal)."""
    model = next((e["model"] for e in race.entries if sub and e["tag"] == sub.pk), None)
    cars = [{"model": e["model"], "name": e["name"], "finished": True} for e in race.entries]
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED,
                                              results={"winner": model, "cars": cars})  # fmt: skip
    race_finished.send(sender=RaceJob, race_id=race.pk)


def test_the_league_has_one_receiver_of_race_finished():
    league = [r for r in race_finished._live_receivers(RaceJob)[0]
              if r.__module__.startswith("leaderboard")]  # fmt: skip
    assert len(league) == 1


def test_a_race_day_turn_moves_the_queue_and_not_a_bracket(fran):
    event = make_event(fran, bracket_size=4)  # a bracket that runs off the race day
    ada, bo = ranked(event, "ada", 30_000), ranked(event, "bo", 31_000)
    bracket.bracket_seed(event=event, user=fran)
    match = BracketMatch.objects.get(event=event)
    raceday.race_day_add(event=event, user=fran, submission=ada)
    slot = raceday.race_day_launch(event=event, user=fran)
    won_by(slot.race, ada)
    assert RaceDaySlot.objects.get(pk=slot.pk).status == RaceDaySlot.Status.DONE
    match.refresh_from_db()
    assert match.winner_id is None  # the solo run is no bracket race
    assert league_race_finished(race_id=slot.race_id) == RACE_DAY  # and again: no change
    won_by(match.race, bo)  # the bracket's own race: the bracket moves, the queue does not
    match.refresh_from_db()
    assert match.winner_id == bo.pk
    assert league_race_finished(race_id=match.race_id) == BRACKET
    assert RaceDaySlot.objects.filter(event=event).count() == 1
    event.refresh_from_db()
    assert champion(bracket_state(event).draw) == 2


def test_a_match_raced_on_the_race_day_ends_the_turn_then_records_the_winner(fran):
    event = make_event(fran, bracket_size=4, bracket_on_race_day=True)
    ada, _ = ranked(event, "ada", 30_000), ranked(event, "bo", 31_000)
    bracket.bracket_seed(event=event, user=fran)
    slot = raceday.race_day_launch(event=event, user=fran)
    assert slot.match_id is not None
    won_by(slot.race, ada)
    assert RaceDaySlot.objects.get(pk=slot.pk).status == RaceDaySlot.Status.DONE
    assert BracketMatch.objects.get(pk=slot.match_id).winner_id == ada.pk
    assert league_race_finished(race_id=slot.race_id) == RACE_DAY
    assert league_race_finished(race_id=10**9) is None  # not a league race


def test_the_event_keeps_the_seeding_and_the_rows_keep_the_results(fran):
    event = make_event(fran, bracket_size=4)
    subs = [ranked(event, name, 30_000 + i) for i, name in enumerate(("ada", "bo", "cy"))]
    bracket.bracket_seed(event=event, user=fran)  # seed 1 has a bye; 2 v 3 race
    event.refresh_from_db()
    assert event.bracket == {"seeds": [s.pk for s in subs], "withdrawn": []}
    semi = BracketMatch.objects.get(event=event, round=1)
    won_by(semi.race, subs[2])
    event.refresh_from_db()
    assert set(event.bracket) == {"seeds", "withdrawn"}  # no second copy of the results
    state = bracket_state(event)
    assert state.draw.rounds[1][0].bottom == 3 and state.draw.rounds[1][0].top == 1
    final = BracketMatch.objects.get(event=event, round=2)
    assert (final.top_id, final.bottom_id) == (subs[0].pk, subs[2].pk)


def test_the_migration_moves_a_json_bracket_into_the_rows_and_back(fran):
    migration = importlib.import_module("leaderboard.migrations.0006_league_rooms")
    event = make_event(fran, bracket_size=4)
    subs = [ranked(event, name, 30_000 + i) for i, name in enumerate(("ada", "bo", "cy"))]
    seeds = [s.pk for s in subs]
    draw = record_winner(seed_bracket(3), 1, 1, 3)  # the old shape: the draw in the JSON
    event.bracket = {"bracket": draw.to_dict(), "seeds": seeds, "withdrawn": [seeds[1]]}
    event.save()
    migration.forwards(django_apps, None)
    event.refresh_from_db()
    assert event.bracket == {"seeds": seeds, "withdrawn": [seeds[1]]}
    row = BracketMatch.objects.get(event=event, round=1, index=1)
    assert (row.top_id, row.bottom_id, row.winner_id) == (seeds[1], seeds[2], seeds[2])
    assert bracket_state(event).draw == draw
    migration.backwards(django_apps, None)
    event.refresh_from_db()
    assert event.bracket["bracket"] == draw.to_dict()
