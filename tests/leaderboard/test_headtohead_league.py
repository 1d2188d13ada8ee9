"""Head-to-head events (leaderboard/bracket.py): brackets seeded from qualifying, matches as
race jobs of frozen entries, winners going through as races end, failures and withdrawals that
never leave a bracket stuck. Races are "run" here by writing their results as the race worker
would (the races themselves are covered by tests/training). Fran runs the event."""

from __future__ import annotations

import pytest
from league_helpers import make_event, make_model, make_user

from leaderboard import bracket as league_bracket
from leaderboard.access import LeagueError
from leaderboard.bracket_draw import champion
from leaderboard.models import BracketMatch, Event, Notification, Submission
from training.models import JobStatus, RaceJob

pytestmark = pytest.mark.django_db


def qualified(event: Event, count: int) -> list[Submission]:
    """``count`` racers ranked in order (the first is the fastest), each with a frozen entry."""
    subs = []
    for i in range(count):
        racer = make_user(f"racer{i}", alias=f"Racer-{i}")
        model = make_model(racer, name=f"car-{i}")
        subs.append(Submission.objects.create(
            event=event, racer=racer, model=model, model_name=model.name,
            status=Submission.Status.RANKED, ranked=True, score_ms=30_000 + 100 * i,
            best_lap_ms=30_000 + 100 * i, entered_model_id=model.pk,
            frozen_checkpoint=f"league/event-{event.pk}/{i}.zip",
            model_metadata={"action_space": model.action_space,
                            "sensor": ["FRONT_FACING_CAMERA"]},
        ))  # fmt: skip
    return subs


def h2h_event(fran, **extra) -> Event:
    return make_event(fran, race_type="HEAD_TO_BOT", bot_count=2, bot_speed_mps=0.75,
                      ranking_method="TOTAL_TIME", bracket_size=extra.pop("size", 8),
                      bracket_laps=2, **extra)  # fmt: skip


def finish(race: RaceJob, winner_sub: Submission | None, *, finished: bool = True) -> None:
    """Write a race's end as the worker does: COMPLETED with its results."""
    cars = [{"model": e["model"], "name": e["name"], "finished": finished,
             "position": 1 if winner_sub and e["tag"] == winner_sub.pk else 2}
            for e in race.entries]  # fmt: skip
    winner = next((e["model"] for e in race.entries
                   if winner_sub and e["tag"] == winner_sub.pk), None)  # fmt: skip
    RaceJob.objects.filter(pk=race.pk).update(
        status=JobStatus.COMPLETED, results={"winner": winner, "cars": cars}
    )
    league_bracket.bracket_race_finished(race_id=race.pk)


def pairs(event: Event, round_number: int) -> list[tuple[int, int]]:
    seeds = event.bracket["seeds"]
    return [(seeds.index(m.top_id) + 1, seeds.index(m.bottom_id) + 1)
            for m in BracketMatch.objects.filter(event=event, round=round_number)
            if m.race_id]  # fmt: skip


@pytest.mark.parametrize(
    ("entries", "first_round", "byes"),
    [
        (3, [(2, 3)], 1),
        (5, [(4, 5)], 3),
        (8, [(1, 8), (4, 5), (2, 7), (3, 6)], 0),
        (13, [(8, 9), (4, 13), (5, 12), (7, 10), (6, 11)], 3),
    ],
)
def test_the_bracket_is_seeded_from_qualifying_with_byes_to_the_top_seeds(
    fran, entries, first_round, byes
):
    event = h2h_event(fran, size=16 if entries > 8 else 8)
    qualified(event, entries)
    bracket = league_bracket.bracket_seed(event=event, user=fran)
    event.refresh_from_db()
    assert bracket.entries == entries
    assert sorted(pairs(event, 1)) == sorted(first_round)
    assert sum(1 for m in bracket.rounds[0] if m.bye) == byes
    races = RaceJob.objects.filter(bracket_matches__event=event, bracket_matches__round=1)
    assert races.count() == len(first_round)
    race = races.first()
    assert race.purpose == "league" and race.laps == 2 and race.bots == 2
    assert all(e["checkpoint"].startswith("league/") and e["metadata"] for e in race.entries)


def test_winners_go_through_until_a_champion_is_left(fran):
    event = h2h_event(fran)
    subs = qualified(event, 5)  # seeds 1-3 have byes, 4 v 5 races first
    league_bracket.bracket_seed(event=event, user=fran)
    event.refresh_from_db()
    played = 0
    for _ in range(10):
        waiting = BracketMatch.objects.filter(event=event, winner__isnull=True,
                                              race__isnull=False)  # fmt: skip
        if not waiting:
            break
        for match in waiting:
            seeds = event.bracket["seeds"]
            later = max(match.top, match.bottom, key=lambda sub: seeds.index(sub.pk))
            finish(match.race, later)  # the lower-ranked qualifier always wins
            played += 1
            event.refresh_from_db()
    event.refresh_from_db()
    bracket = league_bracket.bracket_state(event).draw
    assert played == 4  # five entries: four races
    assert champion(bracket) == 5
    assert Notification.objects.filter(user=subs[4].racer, message__contains="won").exists()


def test_a_failed_race_is_run_again_once_then_the_better_seed_goes_through(fran):
    event = h2h_event(fran)
    qualified(event, 2)
    league_bracket.bracket_seed(event=event, user=fran)
    match = BracketMatch.objects.get(event=event)
    first = match.race
    RaceJob.objects.filter(pk=first.pk).update(status=JobStatus.FAILED, error="worker lost")
    league_bracket.bracket_race_finished(race_id=first.pk)
    match.refresh_from_db()
    assert match.winner_id is None and match.race_id != first.pk and match.attempts == 2
    RaceJob.objects.filter(pk=match.race_id).update(status=JobStatus.FAILED, error="again")
    league_bracket.bracket_race_finished(race_id=match.race_id)
    match.refresh_from_db()
    assert match.winner_id == match.top_id
    assert "could not be run" in match.note


def test_a_race_nobody_moved_in_goes_to_the_better_seed(fran):
    event = h2h_event(fran)
    qualified(event, 2)
    league_bracket.bracket_seed(event=event, user=fran)
    match = BracketMatch.objects.get(event=event)
    finish(match.race, None, finished=False)
    match.refresh_from_db()
    assert match.winner_id == match.top_id and "better qualifier" in match.note


def test_a_withdrawn_racer_is_out_of_their_queued_race_and_their_next_match(fran):
    event = h2h_event(fran)
    subs = qualified(event, 3)  # 1 has a bye to the final; 2 v 3 races
    league_bracket.bracket_seed(event=event, user=fran)
    match = BracketMatch.objects.get(event=event, round=1)
    league_bracket.bracket_withdraw(event=event, user=subs[2].racer, submission=subs[2])
    race = RaceJob.objects.get(pk=match.race_id)
    out = next(e for e in race.entries if e["tag"] == subs[2].pk)
    assert out["withdrawn"] == "its racer withdrew"
    finish(race, subs[1])
    # The final: seed 1 against seed 2; seed 1 withdraws before it is raced.
    final = BracketMatch.objects.get(event=event, round=2)
    RaceJob.objects.filter(pk=final.race_id).update(status=JobStatus.IN_PROGRESS)
    league_bracket.bracket_withdraw(event=event, user=fran, submission=subs[0])
    final.refresh_from_db()
    assert final.winner_id is None  # a race already on track is run to its end
    finish(final.race, subs[1])
    final.refresh_from_db()
    assert final.winner_id == subs[1].pk


def test_a_match_against_a_racer_who_withdrew_earlier_is_decided_without_a_race(fran):
    event = h2h_event(fran)
    subs = qualified(event, 3)
    league_bracket.bracket_seed(event=event, user=fran)
    # seed 1, in the final
    league_bracket.bracket_withdraw(event=event, user=fran, submission=subs[0])
    finish(BracketMatch.objects.get(event=event, round=1).race, subs[2])
    final = BracketMatch.objects.get(event=event, round=2)
    assert final.winner_id == subs[2].pk and final.race_id is None
    assert final.note == "the opponent withdrew"


def test_only_the_organiser_or_a_facilitator_seeds_and_racers_withdraw_only_themselves(fran, alice):
    event = h2h_event(fran)
    subs = qualified(event, 4)
    with pytest.raises(LeagueError, match="organiser or a race facilitator"):
        league_bracket.bracket_seed(event=event, user=alice)
    league_bracket.bracket_seed(event=event, user=fran)
    with pytest.raises(LeagueError, match="already seeded"):
        league_bracket.bracket_seed(event=event, user=fran)
    with pytest.raises(LeagueError, match="only the racer"):
        league_bracket.bracket_withdraw(event=event, user=subs[1].racer, submission=subs[2])


def test_a_bracket_needs_two_qualifiers_and_a_size(fran):
    event = h2h_event(fran)
    qualified(event, 1)
    with pytest.raises(LeagueError, match="at least two ranked qualifiers"):
        league_bracket.bracket_seed(event=event, user=fran)
    plain = make_event(fran, name="No bracket")
    with pytest.raises(LeagueError, match="has no bracket"):
        league_bracket.bracket_seed(event=plain, user=fran)


def test_a_deleted_model_still_races_from_its_frozen_entry(fran):
    event = h2h_event(fran)
    subs = qualified(event, 2)
    model_id = subs[1].model_id
    subs[1].model.delete()
    league_bracket.bracket_seed(event=event, user=fran)
    race = BracketMatch.objects.get(event=event).race
    assert model_id in race.model_ids


def test_the_bracket_page_seeds_for_the_organiser_and_shows_the_rounds(client, fran, alice):
    event = h2h_event(fran)
    qualified(event, 4)
    url = f"/league/events/{event.pk}/bracket/"
    client.force_login(alice)
    page = client.get(url)
    assert page.status_code == 200 and b"seed-bracket" not in page.content
    client.post(url, {"action": "seed"})
    event.refresh_from_db()
    assert not event.bracket  # a racer cannot seed it
    client.force_login(fran)
    assert b"seed-bracket" in client.get(url).content
    client.post(url, {"action": "seed"})
    event.refresh_from_db()
    assert event.bracket["seeds"]
    fragment = client.get(f"{url}?fragment=1")
    assert fragment.status_code == 200
    assert fragment.content.count(b"data-match=") == 3  # two semi-finals and the final
    assert b"Racer-0 \xc2\xb7 car-0" in fragment.content and b"Final" in fragment.content


def test_race_day_matches_wait_in_the_queue_and_a_failed_one_joins_it_again(fran):
    from leaderboard import raceday
    from leaderboard.models import RaceDaySlot

    event = h2h_event(fran, bracket_on_race_day=True)
    subs = qualified(event, 3)  # seed 1 waits in the final; 2 v 3 joins the queue
    league_bracket.bracket_seed(event=event, user=fran)
    match = BracketMatch.objects.get(event=event, round=1)
    assert match.race_id is None and RaceJob.objects.count() == 0
    slot = raceday.race_day_launch(event=event, user=fran)
    assert slot.match == match and slot.race.paced
    RaceJob.objects.filter(pk=slot.race_id).update(status=JobStatus.FAILED, error="lost")
    raceday.race_day_race_finished(race_id=slot.race_id)  # the order of the league's signal
    league_bracket.bracket_race_finished(race_id=slot.race_id)
    again = RaceDaySlot.objects.get(match=match, status=RaceDaySlot.Status.WAITING)
    assert again.pk != slot.pk
    # While it waits, seed 3 withdraws: the match is decided and the queue skips it.
    league_bracket.bracket_withdraw(event=event, user=fran, submission=subs[2])
    match.refresh_from_db()
    assert match.winner_id == subs[1].pk
    final = raceday.race_day_launch(event=event, user=fran)
    assert final.match.round == 2
    again.refresh_from_db()
    assert again.status == RaceDaySlot.Status.DONE and again.race_id is None


def test_a_missed_race_signal_is_caught_up_by_the_reconcile_task(fran):
    from leaderboard.tasks import reconcile_submissions

    event = h2h_event(fran)
    subs = qualified(event, 2)
    league_bracket.bracket_seed(event=event, user=fran)
    match = BracketMatch.objects.get(event=event)
    race = match.race
    RaceJob.objects.filter(pk=race.pk).update(  # ended, but nobody heard of it
        status=JobStatus.COMPLETED,
        results={"winner": race.entries[1]["model"], "cars": [
            {"model": race.entries[1]["model"], "finished": True}]},
    )  # fmt: skip
    assert reconcile_submissions() == 1
    match.refresh_from_db()
    assert match.winner_id == subs[1].pk
    assert reconcile_submissions() == 0
