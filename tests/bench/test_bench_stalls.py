"""bench/bench_stalls.py's bookkeeping, without training: which action the capped car takes
instead of the fastest, which evaluations count as a stall, and the last line."""

from __future__ import annotations

import pytest

from tests.bench.loader import load_bench


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_stalls") as module:
        yield module


def test_the_capped_car_takes_the_same_steering_at_the_next_slower_speed(bench) -> None:
    from training.rl.presets import RACING

    actions = RACING.actions()
    replace = bench.slower_action(actions)
    assert [(actions[i], actions[j]) for i, j in replace.items()] == [
        ({"steering_angle": 0.0, "speed": 3.5}, {"steering_angle": 0.0, "speed": 3.0})
    ]
    two_fastest = [
        {"steering_angle": -10.0, "speed": 2.0},
        {"steering_angle": 10.0, "speed": 2.0},
        {"steering_angle": -10.0, "speed": 1.0},
    ]  # the fastest right turn has no slower one: it stays
    assert bench.slower_action(two_fastest) == {0: 2}


def test_a_stall_is_a_failed_evaluation_after_the_first_clean_one(bench) -> None:
    kept = [(1, 800, False, b"a"), (2, 1600, True, b"b"), (3, 2400, False, b"c"),
            (4, 3200, True, b"d"), (5, 4000, False, b"e")]  # fmt: skip
    assert bench.stalled(kept) == [(3, 2400, b"c"), (5, 4000, b"e")]
    assert bench.stalled([(1, 800, False, b"a")]) == []  # never clean: still learning


def test_before_clean_adds_the_last_failures_ahead_of_the_first_clean_one(bench) -> None:
    kept = [(1, 800, False, b"a"), (2, 1600, False, b"b"), (3, 2400, True, b"c"),
            (4, 3200, False, b"d")]  # fmt: skip
    assert bench.stalled(kept, before=1) == [(2, 1600, b"b"), (4, 3200, b"d")]
    assert bench.stalled(kept, before=5) == [(1, 800, b"a"), (2, 1600, b"b"), (4, 3200, b"d")]
    never = [(1, 800, False, b"a"), (2, 1600, False, b"b")]
    assert bench.stalled(never, before=1) == [(2, 1600, b"b")]


def test_another_track_gets_the_suites_lap_limit(bench) -> None:
    shared = bench.bt.SHARED
    assert bench.track_lap_limit("reinvent_base", shared, 10.0) == 10.0
    assert bench.track_lap_limit("2022_reinvent_champ", shared, 10.0) == 18.8  # 33.28 m


def test_the_last_line_counts_the_replays_and_compares_capped_with_sampled(bench) -> None:
    off = bench.Drive(clean=False, lap=1, progress=51.0, laps=[], top_speed=3.3, fastest_steps=3)
    clean = bench.Drive(clean=True, lap=4, progress=100.0, laps=[6.0, 6.1, 6.0])
    failures = [
        bench.Failure(12, 41, 31_304, greedy=off, capped=clean, sampled=[clean, off, off, off]),
        bench.Failure(12, 42, 32_928, greedy=off, capped=off, sampled=[off, off, off, off]),
    ]
    assert bench.key_values(failures) == (
        "failed=2 greedy_failed=2 capped_clean=1 sampled_clean=0.12 ratio=4.00"
    )
    assert bench.key_values([]).startswith("failed=0 greedy_failed=0 capped_clean=0")
