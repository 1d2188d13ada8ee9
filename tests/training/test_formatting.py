"""Lap times as text: one formatter, the same text from milliseconds and from seconds, and the
template filters of the console and the league built on it."""

from __future__ import annotations

import pytest
from django.template import Context, Template

from training.formatting import format_lap_ms, format_lap_s


@pytest.mark.parametrize(
    ("ms", "text"),
    [(None, "—"), (0, "00:00.000"), (9876, "00:09.876"), (61005, "01:01.005"),
     (3_600_000, "60:00.000"), (-5, "00:00.000")],
)  # fmt: skip
def test_format_lap_ms(ms, text) -> None:
    assert format_lap_ms(ms) == text


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(None, "—"), (0.0, "00:00.000"), (9.8764, "00:09.876"), (9.8766, "00:09.877"),
     (61.005, "01:01.005"), ("12.5", "00:12.500")],
)  # fmt: skip
def test_format_lap_s(seconds, text) -> None:
    assert format_lap_s(seconds) == text


def render(source: str, **context) -> str:
    return Template(source).render(Context(context))


def test_template_filters_keep_their_names_and_units() -> None:
    console = "{% load racecraft %}{{ lap.time_s|laptime }}"
    assert render(console, lap={"time_s": 61.005}) == "01:01.005"
    assert render(console, lap={"time_s": None}) == "—"
    league = "{% load league %}{{ ms|laptime }} {{ s|laptime_s }}"
    assert render(league, ms=61005, s=61.005) == "01:01.005 01:01.005"
    assert render(league, ms=None, s=None) == "— —"
