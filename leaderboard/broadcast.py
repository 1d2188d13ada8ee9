"""The race-day broadcast: ``/ws/league/events/<event_id>/broadcast/[?watch=<token>]``.

Whoever can see the event joins its broadcast group, and so does anyone without an account
who brings the event's spectator token (an event setting; read-only: viewers only listen).
Anyone else is refused with close code 4404 before the handshake completes. Messages, as JSON:

- a binary message for each frame of the race on track: a 4-byte big-endian length, that many
  bytes of JSON ``{"timing": {...}, "t": <unix time>}``, then the JPEG; built once by the
  race's worker at 15 frames/s (real time) however many watch, and forwarded untouched (the
  timing tower: :func:`training.worker.racelive.race_timing`). A frame older than
  :data:`STALE_FRAME_S` when its turn comes is dropped: a slow viewer skips frames rather
  than fall seconds behind the race;
- ``{"type": "status", ...}``: a race went on track (``started``), or ended (``over``, with
  ``winner`` and ``results``), or the queue changed (``queue``).
"""

from __future__ import annotations

import secrets
import time
from typing import Any
from urllib.parse import parse_qs

from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer

from leaderboard.access import can_view_event
from leaderboard.live import broadcast_group
from leaderboard.models import Event
from training import live

NOT_FOUND = 4404
STALE_FRAME_S = 0.5
"""A frame this old (seconds since the worker built it) is not sent any more."""


def may_watch(user, event: Event, token: str) -> bool:
    """The event's viewers, and anyone with its spectator token while the link is on."""
    if event.spectator_token and token and secrets.compare_digest(token, event.spectator_token):
        return True
    return user is not None and can_view_event(user, event)


class BroadcastConsumer(AsyncJsonWebsocketConsumer):
    group = ""

    @database_sync_to_async
    def watched_event(self) -> Event | None:
        query = parse_qs(self.scope.get("query_string", b"").decode())
        token = (query.get("watch") or [""])[0]
        try:
            event = Event.objects.get(pk=int(self.scope["url_route"]["kwargs"]["event_id"]))
        except (KeyError, ValueError, Event.DoesNotExist):
            return None
        return event if may_watch(self.scope.get("user"), event, token) else None

    async def connect(self) -> None:
        event = await self.watched_event()
        if event is None:
            await self.close(code=NOT_FOUND)
            return
        self.group = broadcast_group(event.pk)
        await self.channel_layer.group_add(self.group, self.channel_name)
        await self.accept()
        await database_sync_to_async(live.mark_watching)(self.group)

    async def disconnect(self, code: int) -> None:
        if self.group:
            await self.channel_layer.group_discard(self.group, self.channel_name)

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        """Viewers only listen; a ping keeps the worker sending frames."""
        if self.group:
            await database_sync_to_async(live.mark_watching)(self.group)

    async def race_frame(self, message: dict) -> None:
        if time.time() - float(message.get("t", 0.0)) > STALE_FRAME_S:
            return
        await self.send(bytes_data=message["payload"])

    async def raceday_status(self, message: dict) -> None:
        await self.send_json({**{k: v for k, v in message.items() if k != "type"},
                              "type": "status"})  # fmt: skip
