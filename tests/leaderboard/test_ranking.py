"""leaderboard.ranking: hand-made tables of laps and leaderboards (pure, no database)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from leaderboard.ranking import (
    AVERAGE_LAP,
    BEST_LAP,
    TOTAL_TIME,
    Entry,
    Lap,
    Rules,
    format_gap,
    leaderboard,
    score_laps,
)


def laps(*spec: int | str) -> list[Lap]:
    """``10000`` is a completed lap of 10 s; ``"x"`` an unfinished one (off track, time up)."""
    return [Lap(time_ms=5000, completed=False) if s == "x" else Lap(int(s), True) for s in spec]


SCORES = [
    # method, min_laps, laps, ranked, score_ms, consecutive
    (BEST_LAP, 1, laps(12000, 11000, 13000), True, 11000, 3),
    (BEST_LAP, 1, laps("x", "x", 9000), True, 9000, 1),
    (BEST_LAP, 3, laps(12000, "x", 11000, 13000), False, None, 2),
    (BEST_LAP, 2, laps(12000, "x", 11000, 13000), True, 11000, 2),
    # best lap counts every completed lap once the run qualifies, even outside the run
    (BEST_LAP, 2, laps(8000, "x", 11000, 13000), True, 8000, 2),
    (BEST_LAP, 1, laps("x", "x", "x"), False, None, 0),
    (BEST_LAP, 1, [], False, None, 0),
    # average: the best window of min_laps consecutive laps
    (AVERAGE_LAP, 3, laps(10000, 11000, 12000), True, 11000, 3),
    (AVERAGE_LAP, 2, laps(15000, 11000, 12000, 9000), True, 10500, 4),
    (AVERAGE_LAP, 2, laps(10000, "x", 11000, 12000), True, 11500, 2),
    (AVERAGE_LAP, 3, laps(10000, 10000, "x", 10000, 10000), False, None, 2),
    (AVERAGE_LAP, 3, laps(10001, 10001, 10002), True, 10001, 3),  # 10001.33 rounds down
    (AVERAGE_LAP, 2, laps(10000, 10001), True, 10001, 2),  # 10000.5 rounds half up
    (AVERAGE_LAP, 1, laps(13000, 12500), True, 12500, 2),
    # total: the first min_laps consecutive laps
    (TOTAL_TIME, 3, laps(10000, 11000, 12000, 5000, 5000), True, 33000, 5),
    (TOTAL_TIME, 2, laps("x", 9000, 9500, "x", 1000, 1000), True, 18500, 2),
    (TOTAL_TIME, 3, laps(10000, 11000, "x"), False, None, 2),
    (TOTAL_TIME, 1, laps("x", 14000), True, 14000, 1),
]


@pytest.mark.parametrize(("method", "min_laps", "run", "ranked", "score", "consecutive"), SCORES)
def test_score_laps(method, min_laps, run, ranked, score, consecutive) -> None:
    result = score_laps(run, Rules(method, min_laps))
    assert result.ranked is ranked
    assert result.score_ms == score
    assert result.consecutive_laps == consecutive


def test_stats_are_summed_and_penalties_stay_in_the_times() -> None:
    run = [
        Lap(12000, True, off_tracks=1, resets=1),  # includes a 2 s off-track penalty
        Lap(10000, True),
        Lap(4000, False, off_tracks=2, collisions=1, resets=3),
    ]
    result = score_laps(run, Rules(BEST_LAP, 1))
    assert (result.best_lap_ms, result.average_lap_ms, result.total_time_ms) == (
        10000,
        10000,
        12000,
    )
    assert (result.off_tracks, result.collisions, result.resets) == (3, 1, 4)


@pytest.mark.parametrize(
    ("max_resets", "ranked", "consecutive"),
    [(None, True, 3), (2, True, 3), (1, False, 1), (0, False, 0)],
)
def test_reset_budget_ends_the_run(max_resets, ranked, consecutive) -> None:
    """A reset on each of the first two laps: over budget, that lap and later ones fail."""
    run = [Lap(10000, True, resets=1), Lap(10000, True, resets=1), Lap(10000, True)]
    result = score_laps(run, Rules(TOTAL_TIME, 3, max_resets=max_resets))
    assert result.ranked is ranked
    assert result.consecutive_laps == consecutive


def test_rules_reject_unknown_methods_and_lap_counts() -> None:
    with pytest.raises(ValueError):
        Rules("FASTEST", 1)
    with pytest.raises(ValueError):
        Rules(BEST_LAP, 0)
    with pytest.raises(ValueError):
        Rules(BEST_LAP, 6)


T0 = datetime(2025, 3, 1, 12, 0, tzinfo=UTC)


def entry(sub: int, racer: int, score: int, minutes: int = 0) -> Entry:
    return Entry(sub, racer, score, T0 + timedelta(minutes=minutes))


BOARDS = [
    # entries, expected [(rank, submission, gap_ms)]
    ([], []),
    ([entry(1, 10, 12000)], [(1, 1, 0)]),
    # a racer keeps their best submission
    ([entry(1, 10, 12000), entry(2, 10, 11000), entry(3, 20, 11500)],
     [(1, 2, 0), (2, 3, 500)]),
    # a tie goes to the earlier submission, across racers...
    ([entry(5, 10, 11000, minutes=5), entry(6, 20, 11000, minutes=1)],
     [(1, 6, 0), (2, 5, 0)]),
    # ...and within one racer's submissions
    ([entry(7, 10, 11000, minutes=9), entry(8, 10, 11000, minutes=3)], [(1, 8, 0)]),
    # same time and instant: the lower id (a total order)
    ([entry(9, 10, 11000), entry(4, 20, 11000)], [(1, 4, 0), (2, 9, 0)]),
    ([entry(1, 1, 30000), entry(2, 2, 10000), entry(3, 3, 20000), entry(4, 4, 95000)],
     [(1, 2, 0), (2, 3, 10000), (3, 1, 20000), (4, 4, 85000)]),
]  # fmt: skip


@pytest.mark.parametrize(("entries", "expected"), BOARDS)
def test_leaderboard(entries, expected) -> None:
    rows = leaderboard(entries)
    assert [(r.rank, r.entry.submission_id, r.gap_ms) for r in rows] == expected


@pytest.mark.parametrize(
    ("ms", "text"), [(0, "—"), (500, "+0.500"), (12345, "+12.345"), (61000, "+01:01.000")]
)
def test_format_gap(ms, text) -> None:
    assert format_gap(ms) == text
