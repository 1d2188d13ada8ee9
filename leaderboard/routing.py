"""Websocket routes of the league; console/routing.py appends them to its list."""

from __future__ import annotations

from django.urls import URLPattern, path

from leaderboard.broadcast import BroadcastConsumer
from leaderboard.consumers import LeaderboardConsumer

websocket_urlpatterns: list[URLPattern] = [
    path("ws/league/events/<int:event_id>/", LeaderboardConsumer.as_asgi()),
    path("ws/league/events/<int:event_id>/broadcast/", BroadcastConsumer.as_asgi()),
]
