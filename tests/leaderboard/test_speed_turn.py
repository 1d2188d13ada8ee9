"""Whose turn it is, as the live speed page polls it (``/league/events/<id>/speed/turn.json``):
Ada, on track, reads her car's speed and what it drives at; Bo (waiting), Charlie and Fran get
the page's 403 sentence; someone who may not see the event gets a 404; no session, the login.
Then Ada's turn ends and Bo's starts: the same poll says so to each."""

from __future__ import annotations

import pytest
from django.test import Client
from django.urls import reverse
from test_speed import _no_speeds_between_tests, day, entry  # noqa: F401 - fixtures

from leaderboard import raceday
from leaderboard.models import Event, EventEntrant
from training.models import JobStatus, RaceJob
from training.services import race_control

pytestmark = pytest.mark.django_db


def turn(user, event: Event):
    client = Client()
    if user is not None:
        client.force_login(user)
    return client.get(reverse("league-race-speed-turn", args=[event.pk]))


def test_the_racer_on_track_reads_their_turn_and_others_the_refusal(
    day,  # noqa: F811 - the fixture imported above
    charlie,
    fran,
):
    event, ada, bo, race = day
    answer = turn(ada.racer, event)
    assert answer.status_code == 200 and answer["Cache-Control"] == "no-store"
    assert answer.json() == {"turn": True, "speed": 1.0, "driving": None}  # not driving yet
    race_control.race_speed_set(race=race, index=0, multiplier="1.25")
    race_control.RaceSpeeds(race.pk, 1).value(0, 0.0)  # the worker drives at it
    assert turn(ada.racer, event).json() == {"turn": True, "speed": 1.25, "driving": 1.25}
    for user in (bo.racer, charlie, fran):
        answer = turn(user, event)
        assert answer.status_code == 403
        assert answer.json() == {
            "turn": False,
            "error": "It is not your turn: only the racer on track changes their speed.",
        }
    anonymous = turn(None, event)
    assert anonymous.status_code == 302 and "/login" in anonymous.url
    Event.objects.filter(pk=event.pk).update(is_private=True)
    EventEntrant.objects.create(event=event, racer=ada.racer)  # admitted through the link
    assert turn(charlie, event).status_code == 404  # may not see the event: no such page
    assert turn(ada.racer, event).status_code == 200  # an entrant still may


def test_the_poll_follows_the_queue_from_one_turn_to_the_next(
    day,  # noqa: F811 - the fixture imported above
    fran,
):
    event, ada, bo, race = day
    assert turn(bo.racer, event).status_code == 403
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED, results={"cars": []})
    raceday.race_day_race_finished(race_id=race.pk)
    over = turn(ada.racer, event)
    assert over.status_code == 403 and "only during your turn" in over.json()["error"]
    raceday.race_day_launch(event=event, user=fran)
    assert turn(bo.racer, event).json() == {"turn": True, "speed": 1.0, "driving": None}


def test_the_page_carries_the_poll_s_address(
    day,  # noqa: F811 - the fixture imported above
):
    event, ada, bo, _ = day
    url = reverse("league-race-speed-turn", args=[event.pk])
    for user, status in ((ada.racer, 200), (bo.racer, 403)):
        client = Client()
        client.force_login(user)
        page = client.get(reverse("league-race-speed", args=[event.pk]))
        assert page.status_code == status and f'data-turn-url="{url}"' in page.content.decode()
