"""Template filters of the league pages."""

from __future__ import annotations

from django import template

from training.formatting import format_lap_ms, format_lap_s

register = template.Library()

# ``laptime`` takes milliseconds (a submission's scores); ``laptime_s`` seconds (a lap table's
# ``time_s``), like the console's ``laptime``.
register.filter("laptime", format_lap_ms)
register.filter("laptime_s", format_lap_s)
