"""Lap times as text, the way DeepRacer shows them: ``MM:SS.mmm``.

The one formatter for every layer above (the console's and the league's template filters, the
league's live updates and admin, the command-line tools). Pure: no Django.
"""

from __future__ import annotations

NO_TIME = "—"
"""What stands for a missing time (an em dash)."""


def format_lap_ms(ms: int | None) -> str:
    """Milliseconds as ``MM:SS.mmm`` (minutes may pass 59; below zero counts as zero).

    ``None`` is :data:`NO_TIME`.
    """
    if ms is None:
        return NO_TIME
    minutes, rest = divmod(max(0, int(ms)), 60_000)
    seconds, millis = divmod(rest, 1000)
    return f"{minutes:02d}:{seconds:02d}.{millis:03d}"


def format_lap_s(seconds: float | None) -> str:
    """Seconds, rounded to the millisecond, as ``MM:SS.mmm``; ``None`` is :data:`NO_TIME`."""
    return format_lap_ms(None if seconds is None else round(float(seconds) * 1000))
