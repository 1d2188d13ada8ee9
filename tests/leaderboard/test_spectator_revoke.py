"""Spectators of a race day (issue 47): turning the spectator link off closes the sockets it
let in at once, through the real channel layer the tests use (Redis), while Fran, who runs the
event, keeps watching; and spectators' race-over messages hold display names and times, never
model or race ids nor the race's error text, which only Fran gets."""

from __future__ import annotations

import json

import pytest
from asgiref.sync import async_to_sync
from channels.db import database_sync_to_async
from channels.routing import URLRouter
from channels.testing import WebsocketCommunicator
from django.contrib.auth.models import AnonymousUser
from league_helpers import make_event, make_model, make_user

from leaderboard import raceday
from leaderboard.broadcast import REVOKED, FrameHub
from leaderboard.live import broadcast_group, race_day_changed, spectator_status
from leaderboard.models import RaceDaySlot, Submission
from leaderboard.routing import websocket_urlpatterns
from training import live
from training.models import JobStatus, RaceJob

pytestmark = pytest.mark.django_db(transaction=True)
LEAKED_ERROR = "Traceback: worker celery@gpu-7#4242 lost /srv/racecraft/var/store"


def entry(event, name: str) -> Submission:
    racer = make_user(name, alias=name.title())
    model = make_model(racer, name=f"{name}-car")
    return Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, entered_model_id=model.pk,
        frozen_checkpoint=f"league/event-{event.pk}/{name}.zip",
        model_metadata={"action_space": model.action_space, "sensor": ["FRONT_FACING_CAMERA"]},
    )  # fmt: skip


def socket(event, *, user, token: str = "") -> WebsocketCommunicator:
    query = f"?watch={token}" if token else ""
    path = f"/ws/league/events/{event.pk}/broadcast/{query}"
    communicator = WebsocketCommunicator(URLRouter(websocket_urlpatterns), path)
    communicator.scope["user"] = user
    return communicator


def keys_in(value) -> set[str]:
    """Every key of every dict in a JSON value, however deep."""
    if isinstance(value, dict):
        return set(value) | {k for v in value.values() for k in keys_in(v)}
    if isinstance(value, list):
        return {k for v in value for k in keys_in(v)}
    return set()


def test_turning_the_link_off_closes_the_open_spectator_sockets_at_once(fran):
    event = make_event(fran, is_private=True)
    token = raceday.race_day_spectator_link(event=event, user=fran, enabled=True)
    channel = live.broadcast_channel(broadcast_group(event.pk))

    async def scenario():
        early, late = (socket(event, user=AnonymousUser(), token=token) for _ in range(2))
        organiser = socket(event, user=fran)
        for viewer in (early, late, organiser):
            assert (await viewer.connect(timeout=10))[0]
        assert len(FrameHub.viewers[channel]) == 3
        await database_sync_to_async(raceday.race_day_spectator_link)(
            event=event, user=fran, enabled=False)  # fmt: skip
        closed = [await viewer.receive_output(timeout=10) for viewer in (early, late)]
        left = len(FrameHub.viewers.get(channel, ()))
        # Nothing reaches a closed spectator any more; Fran still gets the queue's news.
        await database_sync_to_async(race_day_changed)(event.pk, {"queue": True, "paused": True})
        news = await organiser.receive_json_from(timeout=10)
        silent = [await viewer.receive_nothing(timeout=0.5) for viewer in (early, late)]
        refused = socket(event, user=AnonymousUser(), token=token)  # the old link is dead
        again, code = await refused.connect(timeout=10)
        await organiser.disconnect()
        return closed, left, news, silent, again, code

    closed, left, news, silent, again, code = async_to_sync(scenario)()
    assert closed == [{"type": "websocket.close", "code": REVOKED}] * 2
    assert left == 1  # only Fran is still fed frames
    assert news == {"queue": True, "paused": True, "type": "status"}
    assert silent == [True, True]
    assert not again and code == 4404


def test_a_new_link_closes_the_sockets_of_the_old_one(fran):
    event = make_event(fran, is_private=True)
    old = raceday.race_day_spectator_link(event=event, user=fran, enabled=True)

    async def scenario():
        viewer = socket(event, user=AnonymousUser(), token=old)
        assert (await viewer.connect(timeout=10))[0]
        new = await database_sync_to_async(raceday.race_day_spectator_link)(
            event=event, user=fran, enabled=True)  # fmt: skip
        closed = await viewer.receive_output(timeout=10)
        fresh = socket(event, user=AnonymousUser(), token=new)
        ok, _ = await fresh.connect(timeout=10)
        await fresh.disconnect()
        return closed, ok

    closed, ok = async_to_sync(scenario)()
    assert closed == {"type": "websocket.close", "code": REVOKED} and ok


def test_a_spectator_whose_access_message_was_lost_is_closed_at_its_next_ping(fran):
    event = make_event(fran, is_private=True)
    token = raceday.race_day_spectator_link(event=event, user=fran, enabled=True)

    async def scenario():
        viewer = socket(event, user=AnonymousUser(), token=token)
        assert (await viewer.connect(timeout=10))[0]
        await database_sync_to_async(  # the link turned off without the group message
            lambda: type(event).objects.filter(pk=event.pk).update(spectator_token="")
        )()
        quiet = await viewer.receive_nothing(timeout=0.5)
        await viewer.send_json_to({})  # the page's 10-second ping
        return quiet, await viewer.receive_output(timeout=10)

    quiet, closed = async_to_sync(scenario)()
    assert quiet and closed == {"type": "websocket.close", "code": REVOKED}


def test_spectators_race_over_message_holds_names_and_times_not_ids_or_errors(fran):
    event = make_event(fran, is_private=True)
    token = raceday.race_day_spectator_link(event=event, user=fran, enabled=True)
    ada, bo = entry(event, "ada"), entry(event, "bo")
    race = RaceJob.objects.create(
        purpose="league", title="Oval sprint: final", status=JobStatus.FAILED,
        error=LEAKED_ERROR, entries=[{"model": ada.model_id, "name": "ada-car", "tag": ada.pk},
                                     {"model": bo.model_id, "name": "bo-car", "tag": bo.pk}],
        results={"winner": ada.model_id, "cars": [
            {"model": ada.model_id, "name": "ada-car", "position": 1, "finished": True,
             "laps": 3, "total_time_s": 61.25, "reason": "", "status": "finished"},
            {"model": bo.model_id, "name": "bo-car", "position": 2, "finished": False,
             "laps": 2, "total_time_s": 61.25, "reason": LEAKED_ERROR, "status": "out"}]},
    )  # fmt: skip
    RaceDaySlot.objects.create(event=event, submission=ada, position=1, race=race,
                               status=RaceDaySlot.Status.RUNNING)  # fmt: skip

    async def scenario():
        spectator = socket(event, user=AnonymousUser(), token=token)
        organiser = socket(event, user=fran)
        for viewer in (spectator, organiser):
            assert (await viewer.connect(timeout=10))[0]
        await database_sync_to_async(raceday.race_day_race_finished)(race_id=race.pk)
        seen = await spectator.receive_json_from(timeout=10)
        detail = await organiser.receive_json_from(timeout=10)
        for viewer in (spectator, organiser):
            await viewer.disconnect()
        return seen, detail

    seen, detail = async_to_sync(scenario)()
    assert seen["over"] and seen["winner"] == "ada-car" and seen["winner_time_s"] == 61.25
    assert [car["name"] for car in seen["standings"]] == ["ada-car", "bo-car"]
    assert not keys_in(seen) & {"model", "race", "results", "error", "status", "reason", "tag"}
    assert LEAKED_ERROR not in json.dumps(seen)
    assert detail["error"] == LEAKED_ERROR and detail["race"] == race.pk  # Fran's detail
    assert detail["results"]["winner"] == ada.model_id


def test_the_spectator_payload_is_a_whitelist():
    message = {"type": "raceday.status", "over": True, "winner": "ada-car", "race": 7,
               "error": "boom", "internal_new_field": 1,
               "standings": [{"name": "ada-car", "model": 3, "total_time_s": 1.0}]}  # fmt: skip
    assert spectator_status(message) == {
        "type": "status", "over": True, "winner": "ada-car",
        "standings": [{"name": "ada-car", "total_time_s": 1.0}],
    }  # fmt: skip
