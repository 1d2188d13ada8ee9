"""Template filters of the league pages."""

from __future__ import annotations

from django import template

from leaderboard.ranking import format_ms

register = template.Library()


@register.filter
def laptime(ms: int | None) -> str:
    """Milliseconds as ``MM:SS.mmm``."""
    return format_ms(ms)


@register.filter
def laptime_s(seconds: float | None) -> str:
    """Seconds (a lap table's ``time_s``) as ``MM:SS.mmm``."""
    return format_ms(None if seconds is None else round(float(seconds) * 1000))
