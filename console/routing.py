"""Websocket URL patterns (console/asgi.py wraps them in authentication and origin checks)."""

from __future__ import annotations

from django.urls import URLPattern, path

import leaderboard.routing
from console.consumers import EvaluationConsumer, TrainingConsumer

websocket_urlpatterns: list[URLPattern] = [
    path("ws/training/<int:job_id>/", TrainingConsumer.as_asgi()),
    path("ws/evaluation/<int:job_id>/", EvaluationConsumer.as_asgi()),
] + leaderboard.routing.websocket_urlpatterns
