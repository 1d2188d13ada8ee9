"""A frozen clock for django-ratelimit, so that throttle tests never depend on timing.

django-ratelimit counts in fixed windows of ``int(time.time())``; a test that made its
attempts across a window's end would see the count start again. Frozen, no window ends during
a test, and :meth:`FrozenClock.advance` is how a test lets "the window pass" without waiting.
Only the limiter's clock is replaced: the counts are still kept in the real Redis.
"""

from __future__ import annotations

import time

import django_ratelimit.core
import pytest


class FrozenClock:
    """Stands in for the ``time`` module inside django_ratelimit.core (only ``time()``)."""

    def __init__(self) -> None:
        self.now = time.time()

    def time(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


def freeze_ratelimit_clock(monkeypatch: pytest.MonkeyPatch) -> FrozenClock:
    clock = FrozenClock()
    monkeypatch.setattr(django_ratelimit.core, "time", clock)
    return clock
