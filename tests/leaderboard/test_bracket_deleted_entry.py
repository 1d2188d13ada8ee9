"""A bracket whose winner's model or entry is deleted mid-bracket (leaderboard/bracket.py).

Four qualifiers: round 1 is seed 1 v seed 4 and seed 2 v seed 3. Seed 4 ("racer3") beats
seed 1, then:

- their **model** is deleted: nothing changes (the entry keeps its frozen checkpoint and the
  model's id): they race the final from their frozen entry;
- their **entry** goes (their account is deleted, which deletes their submissions): their win
  stands (the draw does not go back: seed 4 is still in the final), and they are out of the
  bracket as if they had withdrawn: a final not yet raced goes to the opponent without a
  race, a final already on track is run to its end and its winner goes through.
"""

from __future__ import annotations

import pytest
from test_headtohead_league import finish, h2h_event, qualified

from leaderboard import bracket as league_bracket
from leaderboard.bracket_draw import champion
from leaderboard.models import BracketMatch, Notification
from leaderboard.selectors import bracket_rounds
from training.models import JobStatus, RaceJob

pytestmark = pytest.mark.django_db


@pytest.fixture
def semi_final(fran):
    """The bracket after round 1's first match: seed 4 beat seed 1; 2 v 3 is still racing."""
    event = h2h_event(fran, size=4)
    subs = qualified(event, 4)
    league_bracket.bracket_seed(event=event, user=fran)
    upset = BracketMatch.objects.get(event=event, round=1, index=0)
    finish(upset.race, subs[3])
    event.refresh_from_db()
    return event, subs


def draw_of(event):
    event.refresh_from_db()
    return league_bracket.bracket_state(event).draw


def test_a_deleted_model_races_the_final_from_its_frozen_entry(semi_final):
    event, subs = semi_final
    model_id = subs[3].model_id
    subs[3].model.delete()
    finish(BracketMatch.objects.get(event=event, round=1, index=1).race, subs[1])
    final = BracketMatch.objects.get(event=event, round=2)
    assert final.race is not None and model_id in final.race.model_ids
    finish(final.race, subs[3])
    assert champion(draw_of(event)) == 4


def test_a_deleted_winner_s_win_stands_and_their_next_match_goes_to_the_opponent(semi_final):
    event, subs = semi_final
    gone = subs[3].pk
    subs[3].racer.delete()  # their account, and with it their entry
    upset = BracketMatch.objects.get(event=event, round=1, index=0)
    assert upset.winner_id == gone  # the result is kept, not nulled
    assert draw_of(event).rounds[1][0].top == 4  # seed 4 is still in the final
    assert gone in event.bracket["withdrawn"]
    # The other semi-final ends: the final is seed 4 (gone) v seed 2, decided without a race.
    finish(BracketMatch.objects.get(event=event, round=1, index=1).race, subs[1])
    final = BracketMatch.objects.get(event=event, round=2)
    assert final.race_id is None and final.winner_id == subs[1].pk
    assert final.note == "the opponent's entry was deleted"
    assert champion(draw_of(event)) == 2
    assert Notification.objects.filter(user=subs[1].racer, message__contains="won").exists()
    # The page still draws the bracket, the gone entry by its seed.
    final_view = bracket_rounds(event)[1][0]
    assert final_view.top == "Seed 4 (withdrawn)" and final_view.winner == final_view.bottom


def test_a_final_on_track_when_the_winner_s_entry_goes_is_run_to_its_end(semi_final):
    event, subs = semi_final
    finish(BracketMatch.objects.get(event=event, round=1, index=1).race, subs[1])
    final = BracketMatch.objects.get(event=event, round=2)
    RaceJob.objects.filter(pk=final.race_id).update(status=JobStatus.IN_PROGRESS)
    gone = subs[3].pk
    subs[3].racer.delete()
    final.refresh_from_db()
    assert final.winner_id is None  # on track: it runs to its end
    finish(final.race, None, finished=False)  # no car moved: the better seed goes through
    final.refresh_from_db()
    assert final.winner_id == subs[1].pk
    assert champion(draw_of(event)) == 2
    assert BracketMatch.objects.get(event=event, round=1, index=0).winner_id == gone


def test_a_champion_whose_entry_goes_stays_the_champion(semi_final):
    event, subs = semi_final
    finish(BracketMatch.objects.get(event=event, round=1, index=1).race, subs[1])
    finish(BracketMatch.objects.get(event=event, round=2).race, subs[3])
    assert champion(draw_of(event)) == 4
    subs[3].racer.delete()
    assert champion(draw_of(event)) == 4  # a finished bracket's result does not change


def test_deleting_the_event_deletes_its_bracket(semi_final):
    event, _ = semi_final
    event.delete()
    assert not BracketMatch.objects.exists()
