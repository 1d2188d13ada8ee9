"""A race day (leaderboard/raceday.py, raceviews.py, broadcast.py): the facilitator's queue and
its order, launching paced and broadcast races, pause, skip, the racer told when up next; who
may run it (Fran) and who may only watch (Alice, and anyone with the spectator link)."""

from __future__ import annotations

import asyncio
import time

import pytest
import redis.asyncio as aioredis
from asgiref.sync import async_to_sync
from channels.routing import URLRouter
from channels.testing import WebsocketCommunicator
from django.conf import settings
from django.contrib.auth.models import AnonymousUser
from league_helpers import make_event, make_model, make_user

from leaderboard import raceday
from leaderboard.access import LeagueError
from leaderboard.live import broadcast_group
from leaderboard.models import Notification, RaceDaySlot, Submission
from leaderboard.routing import websocket_urlpatterns
from racing.framecodec import decode_frame, encode_frame
from training import live
from training.models import JobStatus, RaceJob

pytestmark = pytest.mark.django_db


def entry(event, name: str) -> Submission:
    racer = make_user(name, alias=name.title())
    model = make_model(racer, name=f"{name}-car")
    return Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, entered_model_id=model.pk,
        frozen_checkpoint=f"league/event-{event.pk}/{name}.zip",
        model_metadata={"action_space": model.action_space, "sensor": ["FRONT_FACING_CAMERA"]},
    )  # fmt: skip


def queue_of(event) -> list[tuple[str, str]]:
    return [(s.submission.model_name, s.status) for s in
            RaceDaySlot.objects.filter(event=event).select_related("submission")]  # fmt: skip


def test_the_queue_keeps_the_facilitators_order_and_moves_on(fran):
    event = make_event(fran)
    ada, bo, cy = entry(event, "ada"), entry(event, "bo"), entry(event, "cy")
    slots = [raceday.race_day_add(event=event, user=fran, submission=s) for s in (ada, bo, cy)]
    raceday.race_day_move(slot=slots[2], user=fran, up=True)
    assert [name for name, _ in queue_of(event)] == ["ada-car", "cy-car", "bo-car"]
    assert Notification.objects.filter(user=ada.racer, message__contains="up next").count() == 1

    first = raceday.race_day_launch(event=event, user=fran)
    race = first.race
    assert race.paced and race.broadcast_group == broadcast_group(event.pk)
    assert race.purpose == "league" and race.entries[0]["tag"] == ada.pk
    assert len(race.entries) == 1 and race.laps == event.max_laps  # a solo run
    assert Notification.objects.filter(user=cy.racer, message__contains="up next").exists()
    with pytest.raises(LeagueError, match="a race is on track"):
        raceday.race_day_launch(event=event, user=fran)

    RaceJob.objects.filter(pk=race.pk).update(
        status=JobStatus.COMPLETED, results={"winner": ada.model_id, "cars": []}
    )
    raceday.race_day_race_finished(race_id=race.pk)
    assert queue_of(event)[0] == ("ada-car", "DONE")
    raceday.race_day_skip(slot=RaceDaySlot.objects.get(submission=cy), user=fran)
    second = raceday.race_day_launch(event=event, user=fran)
    assert second.submission == bo
    assert queue_of(event) == [("ada-car", "DONE"), ("cy-car", "SKIPPED"), ("bo-car", "RUNNING")]


def test_a_failed_race_ends_its_turn_so_the_day_goes_on(fran):
    event = make_event(fran)
    raceday.race_day_add(event=event, user=fran, submission=entry(event, "ada"))
    raceday.race_day_add(event=event, user=fran, submission=entry(event, "bo"))
    slot = raceday.race_day_launch(event=event, user=fran)
    RaceJob.objects.filter(pk=slot.race_id).update(status=JobStatus.FAILED, error="lost")
    raceday.race_day_race_finished(race_id=slot.race_id)
    assert raceday.race_day_launch(event=event, user=fran).submission.model_name == "bo-car"


def test_a_paused_day_launches_nothing_until_it_resumes(fran):
    event = make_event(fran)
    raceday.race_day_add(event=event, user=fran, submission=entry(event, "ada"))
    raceday.race_day_pause(event=event, user=fran, paused=True)
    with pytest.raises(LeagueError, match="paused"):
        raceday.race_day_launch(event=event, user=fran)
    raceday.race_day_pause(event=event, user=fran, paused=False)
    assert raceday.race_day_launch(event=event, user=fran).status == RaceDaySlot.Status.RUNNING
    with pytest.raises(LeagueError, match="queue is empty"):
        RaceJob.objects.update(status=JobStatus.COMPLETED)
        raceday.race_day_race_finished(race_id=RaceJob.objects.get().pk)
        raceday.race_day_launch(event=event, user=fran)


def test_a_racer_who_is_not_a_facilitator_is_refused_every_control(fran, alice):
    event = make_event(fran)
    sub = entry(event, "ada")
    slot = raceday.race_day_add(event=event, user=fran, submission=sub)
    for call in (
        lambda: raceday.race_day_add(event=event, user=alice, submission=sub),
        lambda: raceday.race_day_launch(event=event, user=alice),
        lambda: raceday.race_day_skip(slot=slot, user=alice),
        lambda: raceday.race_day_move(slot=slot, user=alice, up=False),
        lambda: raceday.race_day_pause(event=event, user=alice, paused=True),
        lambda: raceday.race_day_stop(event=event, user=alice),
        lambda: raceday.race_day_spectator_link(event=event, user=alice, enabled=True),
    ):
        with pytest.raises(LeagueError, match="organiser or a race facilitator"):
            call()
    assert RaceJob.objects.count() == 0


def test_the_race_day_page_refuses_a_racer_and_serves_the_facilitator(client, fran, alice):
    event = make_event(fran)
    client.force_login(alice)
    refused = client.get(f"/league/events/{event.pk}/race-day/")
    assert refused.status_code == 403 and b"Launch next" not in refused.content
    assert client.post(f"/league/events/{event.pk}/race-day/",
                       {"action": "launch"}).status_code == 403  # fmt: skip
    client.force_login(fran)
    page = client.get(f"/league/events/{event.pk}/race-day/")
    assert page.status_code == 200 and b"Launch next" in page.content
    sub = entry(event, "ada")
    client.post(f"/league/events/{event.pk}/race-day/", {"action": "add", "submission": sub.pk})
    client.post(f"/league/events/{event.pk}/race-day/", {"action": "launch"})
    assert RaceDaySlot.objects.get().status == RaceDaySlot.Status.RUNNING


def test_stop_on_the_page_says_whether_the_race_was_canceled_or_is_stopping(client, fran):
    event = make_event(fran)
    url = f"/league/events/{event.pk}/race-day/"
    client.force_login(fran)
    for name in ("ada", "bo"):
        client.post(url, {"action": "add", "submission": entry(event, name).pk})
    client.post(url, {"action": "launch"})
    page = client.post(url, {"action": "stop"}, follow=True)  # no worker has claimed it
    assert b"it is canceled, and the next turn can go on track" in page.content
    assert RaceJob.objects.get().status == JobStatus.CANCELED
    client.post(url, {"action": "launch"})
    RaceJob.objects.filter(status=JobStatus.QUEUED).update(status=JobStatus.IN_PROGRESS)
    page = client.post(url, {"action": "stop"}, follow=True)
    assert b"The race on track is stopping." in page.content
    assert RaceJob.objects.get(status=JobStatus.IN_PROGRESS).stop_requested


def test_the_broadcast_page_needs_the_event_or_the_spectator_link(client, fran):
    event = make_event(fran, is_private=True)
    url = f"/league/events/{event.pk}/broadcast/"
    assert client.get(url).status_code == 404
    token = raceday.race_day_spectator_link(event=event, user=fran, enabled=True)
    page = client.get(f"{url}?watch={token}")
    assert page.status_code == 200 and b"data-broadcast" in page.content
    assert client.get(f"{url}?watch=wrong-{token}").status_code == 404
    raceday.race_day_spectator_link(event=event, user=fran, enabled=False)
    assert client.get(f"{url}?watch={token}").status_code == 404


@pytest.mark.django_db(transaction=True)
def test_the_broadcast_socket_relays_frames_to_spectators_with_the_link(fran):
    event = make_event(fran, is_private=True)
    token = raceday.race_day_spectator_link(event=event, user=fran, enabled=True)
    app = URLRouter(websocket_urlpatterns)

    async def scenario():
        outsider = WebsocketCommunicator(app, f"/ws/league/events/{event.pk}/broadcast/")
        outsider.scope["user"] = AnonymousUser()
        refused, code = await outsider.connect(timeout=10)
        viewer = WebsocketCommunicator(
            app, f"/ws/league/events/{event.pk}/broadcast/?watch={token}"
        )
        viewer.scope["user"] = AnonymousUser()
        ok, _ = await viewer.connect(timeout=10)
        from channels.layers import get_channel_layer

        layer = get_channel_layer()
        timing = {"clock_s": 1.0, "laps": 2, "over": False, "cars": []}
        channel = live.broadcast_channel(broadcast_group(event.pk))
        publisher = aioredis.Redis.from_url(settings.REDIS_URL)
        for _ in range(100):  # the hub subscribes as the viewer connects
            if dict(await publisher.pubsub_numsub(channel)).get(channel.encode()):
                break
            await asyncio.sleep(0.05)
        now = time.time()
        await publisher.publish(channel, b"\x00\x00\x00\x05{nope")  # unreadable: dropped
        # Built 5 s ago: still shown unless a newer one replaced it (never none on a slow box).
        await publisher.publish(channel, encode_frame({"timing": timing, "t": now - 5}, b"old"))
        fresh = encode_frame({"timing": timing, "t": now}, b"\xff\xd8jpeg")
        await publisher.publish(channel, fresh)
        await publisher.aclose()
        frames = [await viewer.receive_from(timeout=10)]
        while frames[-1] != fresh and len(frames) < 2:
            frames.append(await viewer.receive_from(timeout=10))
        await layer.group_send(
            broadcast_group(event.pk), {"type": "raceday.status", "over": True, "winner": "Ada"}
        )
        status = await viewer.receive_json_from(timeout=10)
        await viewer.disconnect()
        return refused, code, ok, frames, status

    refused, code, ok, frames, status = async_to_sync(scenario)()
    assert not refused and code == 4404
    assert [decode_frame(f)[1] for f in frames[:-1]] in ([], [b"old"])  # the unreadable: never
    header, jpeg = decode_frame(frames[-1])  # the newest frame always reaches the viewer
    assert ok and jpeg == b"\xff\xd8jpeg"
    assert header["timing"] == {"clock_s": 1.0, "laps": 2, "over": False, "cars": []}
    assert status == {"type": "status", "over": True, "winner": "Ada"}
    assert live.is_watched(broadcast_group(event.pk))  # a viewer keeps the worker sending
