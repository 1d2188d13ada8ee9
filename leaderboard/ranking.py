"""Scores and leaderboards: pure functions over plain dataclasses (no Django, no I/O).

Times are integer milliseconds and include penalties (the car is frozen for the penalty and the
clock runs). A submission is *ranked* when its evaluation has at least ``min_laps`` consecutive
completed laps; then, by the event's method (DeepRacer's ``TimingMethod``):

``BEST_LAP``     the fastest completed lap of the submission.
``AVERAGE_LAP``  the lowest mean over any window of ``min_laps`` consecutive completed laps,
                 rounded half up to the millisecond.
``TOTAL_TIME``   the sum of the first ``min_laps`` consecutive completed laps.

Lower wins. On a leaderboard each racer keeps their best submission; equal scores go to the
earlier submission (then the lower id, so the order is total).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime

from training.formatting import format_lap_ms

BEST_LAP, AVERAGE_LAP, TOTAL_TIME = "BEST_LAP", "AVERAGE_LAP", "TOTAL_TIME"
METHODS = (BEST_LAP, AVERAGE_LAP, TOTAL_TIME)


@dataclass(frozen=True)
class Lap:
    """One trial of an evaluation. ``time_ms`` includes penalties."""

    time_ms: int
    completed: bool
    off_tracks: int = 0
    collisions: int = 0
    resets: int = 0


@dataclass(frozen=True)
class Rules:
    """``min_laps`` 1-5; ``max_resets`` None for unlimited: once the racer's resets exceed it,
    the lap where that happened and every later lap count as not completed."""

    method: str
    min_laps: int
    max_resets: int | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown ranking method {self.method!r}")
        if not 1 <= self.min_laps <= 5:
            raise ValueError("min_laps is 1-5")


@dataclass(frozen=True)
class Score:
    ranked: bool
    score_ms: int | None
    best_lap_ms: int | None
    average_lap_ms: int | None
    total_time_ms: int | None
    consecutive_laps: int
    off_tracks: int
    collisions: int
    resets: int


def _mean_ms(times: Sequence[int]) -> int:
    """Mean rounded half up, in integers (no float drift)."""
    n = len(times)
    return (2 * sum(times) + n) // (2 * n)


def _runs(completed: Sequence[bool]) -> list[tuple[int, int]]:
    """(start, length) of every run of consecutive completed laps, in order."""
    runs, start = [], None
    for i, done in enumerate([*completed, False]):
        if done and start is None:
            start = i
        elif not done and start is not None:
            runs.append((start, i - start))
            start = None
    return runs


def _within_reset_budget(laps: Sequence[Lap], max_resets: int | None) -> list[bool]:
    if max_resets is None:
        return [lap.completed for lap in laps]
    used, out = 0, []
    for lap in laps:
        used += lap.resets
        out.append(lap.completed and used <= max_resets)
    return out


def score_laps(laps: Sequence[Lap], rules: Rules) -> Score:
    """The score of one submission's laps under ``rules`` (see the module docstring)."""
    completed = _within_reset_budget(laps, rules.max_resets)
    times = [lap.time_ms for lap, done in zip(laps, completed, strict=True) if done]
    runs = _runs(completed)
    longest = max((length for _, length in runs), default=0)
    k = rules.min_laps
    windows = [
        [laps[i].time_ms for i in range(start + j, start + j + k)]
        for start, length in runs
        for j in range(length - k + 1)
    ]
    best = min(times) if times else None
    average = min((_mean_ms(w) for w in windows), default=None)
    total = sum(windows[0]) if windows else None
    ranked = longest >= k
    score = {BEST_LAP: best, AVERAGE_LAP: average, TOTAL_TIME: total}[rules.method]
    return Score(
        ranked=ranked,
        score_ms=score if ranked else None,
        best_lap_ms=best,
        average_lap_ms=average,
        total_time_ms=total,
        consecutive_laps=longest,
        off_tracks=sum(lap.off_tracks for lap in laps),
        collisions=sum(lap.collisions for lap in laps),
        resets=sum(lap.resets for lap in laps),
    )


@dataclass(frozen=True)
class Entry:
    """A ranked submission as the leaderboard sees it."""

    submission_id: int
    racer_id: int
    score_ms: int
    submitted_at: datetime


@dataclass(frozen=True)
class Row:
    rank: int
    entry: Entry
    gap_ms: int


def _order(entry: Entry) -> tuple[int, datetime, int]:
    return (entry.score_ms, entry.submitted_at, entry.submission_id)


def best_per_racer(entries: Iterable[Entry]) -> list[Entry]:
    """Each racer's best entry (ties: the earlier submission)."""
    best: dict[int, Entry] = {}
    for entry in entries:
        kept = best.get(entry.racer_id)
        if kept is None or _order(entry) < _order(kept):
            best[entry.racer_id] = entry
    return list(best.values())


def leaderboard(entries: Iterable[Entry]) -> list[Row]:
    """Ranks 1..n over each racer's best entry; ``gap_ms`` is the time behind the leader."""
    ordered = sorted(best_per_racer(entries), key=_order)
    if not ordered:
        return []
    first = ordered[0].score_ms
    return [Row(rank=i, entry=e, gap_ms=e.score_ms - first) for i, e in enumerate(ordered, 1)]


def format_gap(ms: int) -> str:
    """``+S.mmm`` seconds behind the leader (minutes when a minute or more); ``—`` for first."""
    if ms <= 0:
        return "—"
    if ms >= 60_000:
        return f"+{format_lap_ms(ms)}"
    return f"+{ms // 1000}.{ms % 1000:03d}"
