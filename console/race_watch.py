"""A racer's own race, live: ``/ws/races/<race_id>/``.

Only the racer who started the race from the Races page (its challenger,
:func:`training.services.challenges.challenge_role`) may watch; anyone else is closed with
4404 before the handshake completes. The frames are the race's broadcast frames (built once
by the worker, published once to the race group's Redis channel, written untouched to each
viewer by :class:`leaderboard.broadcast.FrameHub`, as on a race day's broadcast page); the
race's status changes come as the race-day broadcast's status messages
(:func:`race_status`: ``started``, or ``over`` with the ``winner`` and ``winner_time_s``),
plus the job's ``status`` and an ``outcome`` word, so one page script
(static/leaderboard/broadcast.js) serves both. A ping from the page (every 10 s) keeps the
worker encoding frames.
"""

from __future__ import annotations

from typing import Any

from channels.consumer import get_handler_name
from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer

from leaderboard.broadcast import FrameHub
from training import live
from training.models import RaceJob
from training.services import challenges

NOT_FOUND = 4404
OUTCOMES = {"COMPLETED": "Finished", "FAILED": "Failed", "CANCELED": "Canceled"}
STARTED = ("INITIALIZING", "IN_PROGRESS")


def race_status(status: str | None, results: dict | None) -> dict:
    """A race job's status as the broadcast page's status message: ``started`` while on
    track; once ended ``over``, the ``outcome`` (``Stopped`` for a race its challenger
    stopped) and the winner's name and time from the results (none for no winner)."""
    message: dict[str, Any] = {"type": "status", "status": status}
    if status in STARTED:
        message["started"] = True
    elif status in OUTCOMES:
        results = results or {}
        key = results.get("winner")
        cars = results.get("cars") or []
        winner = next((c for c in cars if key is not None and c.get("model") == key), None)
        stopped = status == "COMPLETED" and results.get("stopped")
        message.update(over=True, outcome="Stopped" if stopped else OUTCOMES[status],
                       winner=winner.get("name") if winner else None,
                       winner_time_s=winner.get("total_time_s") if winner else None)  # fmt: skip
    return message


class RaceWatchConsumer(AsyncJsonWebsocketConsumer):
    group = ""

    @database_sync_to_async
    def _race(self) -> RaceJob | None:
        """The URL's race when this viewer is its challenger, else None."""
        try:
            race_id = int(self.scope["url_route"]["kwargs"]["race_id"])
            race, _ = challenges.challenge_for(user=self.scope.get("user"), race_id=race_id,
                                               challenger_only=True)  # fmt: skip
        except (KeyError, ValueError, RaceJob.DoesNotExist):
            return None
        return race

    async def connect(self) -> None:
        race = await self._race()
        if race is None:
            await self.close(code=NOT_FOUND)
            return
        self.group = live.job_group("race", race.pk)
        await self.channel_layer.group_add(self.group, self.channel_name)
        await self.accept()
        FrameHub.join(live.broadcast_channel(self.group), self)
        await database_sync_to_async(live.mark_watching)(self.group)
        # Where the race is now: a page opened after it ended is told at once.
        await self.send_json(race_status(race.status, None if race.is_active else race.results))

    async def disconnect(self, code: int) -> None:
        if self.group:
            group, self.group = self.group, ""
            FrameHub.leave(live.broadcast_channel(group), self)
            await self.channel_layer.group_discard(group, self.channel_name)

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        if self.group:
            await database_sync_to_async(live.mark_watching)(self.group)

    async def dispatch(self, message: dict) -> None:
        """Messages to the race's group that this page has no use for are skipped (Channels
        would close the socket on a message type without a handler)."""
        if getattr(self, get_handler_name(message), None) is None and not str(
            message.get("type", "")
        ).startswith("websocket."):
            return
        await super().dispatch(message)

    async def job_status(self, message: dict) -> None:
        if self.group:
            await self.send_json(race_status(message.get("status"), message.get("results")))
