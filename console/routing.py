"""Websocket URL patterns; consumers arrive with the training and leaderboard issues."""

from __future__ import annotations

from django.urls import URLPattern

websocket_urlpatterns: list[URLPattern] = []
