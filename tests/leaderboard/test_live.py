"""The live leaderboard websocket over the real channel layer (Redis): a snapshot on connect,
then the new board when a result lands; private events refuse outsiders."""

from __future__ import annotations

import pytest
from asgiref.sync import async_to_sync
from channels.auth import AuthMiddlewareStack
from channels.routing import URLRouter
from channels.testing import WebsocketCommunicator
from django.contrib.auth.models import AnonymousUser
from league_helpers import finish_evaluation, lap, make_event, make_model

from leaderboard.routing import websocket_urlpatterns
from leaderboard.services import submission_create

pytestmark = pytest.mark.django_db(transaction=True)


def app():
    return URLRouter(websocket_urlpatterns)


async def connect(event_id: int, user) -> tuple[WebsocketCommunicator, bool, int | None]:
    communicator = WebsocketCommunicator(app(), f"/ws/league/events/{event_id}/")
    communicator.scope["user"] = user
    connected, code = await communicator.connect(timeout=10)
    return communicator, connected, code


def test_a_result_reaches_the_watchers(fran, alice, bob):
    event = make_event(fran)
    sub = submission_create(event=event, user=alice, model=make_model(alice))

    async def scenario() -> tuple[dict, dict]:
        communicator, connected, _ = await connect(event.pk, AnonymousUser())
        assert connected
        snapshot = await communicator.receive_json_from(timeout=10)
        from channels.db import database_sync_to_async

        await database_sync_to_async(finish_evaluation)(sub.evaluation, [lap(10.5), lap(9.875)])
        update = await communicator.receive_json_from(timeout=10)
        await communicator.disconnect()
        return snapshot, update

    snapshot, update = async_to_sync(scenario)()
    assert snapshot == {"type": "snapshot", "rows": []}
    assert update["type"] == "result"
    assert update["submission"]["id"] == sub.pk and update["submission"]["status"] == "RANKED"
    assert update["submission"]["time"] == "00:09.875"
    (row,) = update["rows"]
    assert (row["rank"], row["alias"], row["time"]) == (1, "Alice-R", "00:09.875")


def test_private_events_refuse_outsiders(alice, bob):
    from django.utils import timezone

    from leaderboard.events import event_create

    race = event_create(organiser=alice, is_private=True, name="Secret", track_id="racecraft_oval",
                        opens_at=timezone.now(),
                        closes_at=timezone.now() + timezone.timedelta(days=1))  # fmt: skip

    async def scenario():
        outsider, ok_outsider, code = await connect(race.pk, bob)
        anonymous, ok_anon, _ = await connect(race.pk, AnonymousUser())
        owner, ok_owner, _ = await connect(race.pk, alice)
        if ok_owner:
            await owner.receive_json_from(timeout=10)
            await owner.disconnect()
        return ok_outsider, code, ok_anon, ok_owner

    ok_outsider, code, ok_anon, ok_owner = async_to_sync(scenario)()
    assert (ok_outsider, ok_anon, ok_owner) == (False, False, True)
    assert code == 4404


def test_the_asgi_application_routes_the_league_socket():
    from console.routing import websocket_urlpatterns as console_patterns

    assert any("ws/league/events/" in str(p.pattern) for p in console_patterns)
    assert AuthMiddlewareStack  # the real app wraps the routes in session auth


def test_others_see_a_failed_result_neither_its_status_nor_its_reason(fran, alice, bob):
    from training.models import JobStatus

    event = make_event(fran)
    sub = submission_create(event=event, user=alice, model=make_model(alice))

    async def scenario() -> tuple[dict, dict]:
        from channels.db import database_sync_to_async

        watchers = []
        for user in (alice, bob):
            communicator, connected, _ = await connect(event.pk, user)
            assert connected
            await communicator.receive_json_from(timeout=10)  # the snapshot
            watchers.append(communicator)
        await database_sync_to_async(finish_evaluation)(
            sub.evaluation, [], status=JobStatus.FAILED, error="secret reason of alice's"
        )
        seen = [await c.receive_json_from(timeout=10) for c in watchers]
        for communicator in watchers:
            await communicator.disconnect()
        return seen[0], seen[1]

    hers, his = async_to_sync(scenario)()
    assert hers["submission"]["id"] == sub.pk and hers["submission"]["status"] == "FAILED"
    assert "secret reason" in hers["submission"]["reason"]
    assert his == {"type": "result", "submission": None, "rows": []}
