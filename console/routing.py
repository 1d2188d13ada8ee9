"""Websocket URL patterns (console/asgi.py wraps them in authentication and origin checks)."""

from __future__ import annotations

from django.urls import URLPattern, path

import leaderboard.routing
from console.consumers import EvaluationConsumer, TrainingConsumer
from console.race_watch import RaceWatchConsumer

websocket_urlpatterns: list[URLPattern] = [
    path("ws/training/<int:job_id>/", TrainingConsumer.as_asgi()),
    path("ws/evaluation/<int:job_id>/", EvaluationConsumer.as_asgi()),
    path("ws/races/<int:race_id>/", RaceWatchConsumer.as_asgi()),  # a racer's race, live
] + leaderboard.routing.websocket_urlpatterns
