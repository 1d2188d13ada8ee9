"""Template filters of the console: status badges, lap times, durations."""

from __future__ import annotations

from django import template

from racing.rules import STATUS_LABELS, Status
from training.formatting import format_lap_s

register = template.Library()
register.filter("laptime", format_lap_s)  # seconds (a lap's time_s) as MM:SS.mmm

BADGES = {
    "READY": "ok", "COMPLETED": "ok",
    "TRAINING": "busy", "IN_PROGRESS": "busy", "EVALUATING": "busy", "INITIALIZING": "busy",
    "QUEUED": "wait", "STOPPING": "wait", "DELETING": "wait",
    "ERROR": "bad", "FAILED": "bad", "CANCELED": "off",
}  # fmt: skip


@register.filter
def badge(status: str) -> str:
    """CSS modifier of a status badge: ok, busy, wait, bad or off."""
    return BADGES.get(str(status), "off")


@register.filter
def duration(seconds: float | None) -> str:
    """Seconds as H:MM:SS (or M:SS under an hour)."""
    total = int(seconds or 0)
    hours, rest = divmod(total, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


@register.filter
def lap_status(value: str) -> str:
    """An episode status value (``lap_complete``) as its label (``Lap complete``)."""
    try:
        return STATUS_LABELS[Status(value)]
    except ValueError:
        return str(value).replace("_", " ").capitalize()


@register.filter
def get_item(mapping: dict, key: str) -> object:
    return mapping.get(key, key) if isinstance(mapping, dict) else key
