"""The live leaderboard: ``/ws/league/events/<event_id>/``.

Whoever can see the event (:func:`~leaderboard.access.can_view_event`: everyone for public
events, organiser/facilitators/entrants for private ones) joins the event's group; anyone else
is refused with close code 4404 before the handshake completes. Messages, as JSON:

- ``{"type": "snapshot", "rows": [...]}`` on connect;
- ``{"type": "bracket"}`` when the event's bracket moved on (the page fetches it again);
- ``{"type": "result", "submission": {...} | null, "rows": [...]}`` when a result lands: the
  whole leaderboard (rows as :class:`~leaderboard.selectors.LeaderboardRow`) and the
  submission that just finished as the pages show it to this viewer
  (:func:`~leaderboard.live.visible_result`): their own whole, another racer's only once
  ranked and without its reason, else null.
"""

from __future__ import annotations

from typing import Any

from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer

from leaderboard.access import can_view_event
from leaderboard.live import event_group, visible_result
from leaderboard.models import Event
from leaderboard.selectors import leaderboard_rows

NOT_FOUND = 4404


class LeaderboardConsumer(AsyncJsonWebsocketConsumer):
    group = ""

    @database_sync_to_async
    def visible_event(self) -> tuple[Event, list[dict]] | None:
        """The URL's event and its rows when the user may see it, else None (the only check)."""
        user = self.scope.get("user")
        try:
            event = Event.objects.get(pk=int(self.scope["url_route"]["kwargs"]["event_id"]))
        except (KeyError, ValueError, Event.DoesNotExist):
            return None
        if user is None or not can_view_event(user, event):
            return None
        return event, [row.as_dict() for row in leaderboard_rows(event)]

    async def connect(self) -> None:
        found = await self.visible_event()
        if found is None:
            await self.close(code=NOT_FOUND)
            return
        event, rows = found
        self.group = event_group(event.pk)
        await self.channel_layer.group_add(self.group, self.channel_name)
        await self.accept()
        await self.send_json({"type": "snapshot", "rows": rows})

    async def disconnect(self, code: int) -> None:
        if self.group:
            await self.channel_layer.group_discard(self.group, self.channel_name)

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        """Viewers only listen."""

    async def league_bracket(self, message: dict) -> None:
        await self.send_json({"type": "bracket"})

    async def league_result(self, message: dict) -> None:
        user = self.scope.get("user")
        await self.send_json(visible_result(message, getattr(user, "pk", None)))
