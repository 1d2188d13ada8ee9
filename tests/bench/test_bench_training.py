"""bench/bench_training.py's bookkeeping, without training: the streak that defines the goal,
the medians (a missed goal is never averaged away), the laps and the last line."""

from __future__ import annotations

import pytest

from tests.bench.loader import load_bench


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_training") as module:
        yield module


def test_the_streak_needs_three_clean_evaluations_in_a_row(bench) -> None:
    streak = bench.Streak()
    assert not streak.add(True, [30.0, 31.0, 30.5])
    assert not streak.add(True, [30.0, 31.0, 30.5])
    assert not streak.add(False, [30.0])  # off track on the second lap: start again
    assert not streak.add(True, [29.0, 29.0, 29.0])
    assert not streak.add(True, [29.0, 29.0])  # two laps are not three
    assert [streak.add(True, [28.0] * 3) for _ in range(3)] == [False, False, True]
    assert streak.evaluations == [[28.0] * 3] * 3


def test_the_fast_goal_counts_only_evaluations_with_every_lap_within_the_limit(bench) -> None:
    streak = bench.Streak(lap_limit_s=10.0)
    assert not streak.add(True, [9.5, 9.8, 10.0])
    assert not streak.add(True, [9.5, 10.01, 9.0])  # one slow lap breaks the streak
    assert streak.evaluations == []
    assert [streak.add(True, [9.9, 9.7, 9.6]) for _ in range(3)] == [False, False, True]


def run(bench, seconds, steps, laps=(), best=None):
    r = bench.Run("fast", 0, seconds=seconds, steps=steps, best_lap_s=best)
    r.qualifying_laps = [list(ev) for ev in laps]
    return r


def test_medians_laps_and_best_lap(bench) -> None:
    runs = [
        run(bench, 100.0, 30_000, [[9.0, 9.5, 9.9]] * 3, best=8.9),
        run(bench, 140.0, 41_000, [[9.8, 9.8, 9.8]] * 3, best=9.1),
        run(bench, 90.0, 28_000, [[9.2, 9.3, 9.4]] * 3, best=8.7),
    ]
    s = bench.summarise(runs)
    assert (s.median_s, s.median_steps, s.reached, s.runs) == (100.0, 30_000.0, 3, 3)
    assert s.worst_s == 140.0
    assert s.lap_s == 9.5  # the 14th of the 27 qualifying laps
    assert s.best_lap_s == 8.7


def test_a_seed_that_missed_its_goal_makes_the_median_nan(bench) -> None:
    runs = [run(bench, 100.0, 30_000, [[9.0] * 3] * 3, 8.8), run(bench, None, None, best=9.9)]
    s = bench.summarise(runs)
    assert s.median_s is None and s.median_steps is None and s.reached == 1
    assert s.worst_s is None  # a miss and no time limit: unknown
    assert bench.summarise(runs, limit_s=480.0).worst_s == 480.0  # the miss counts as its limit
    assert s.lap_s == 9.0 and s.best_lap_s == 8.8
    assert s.seed_best_s == pytest.approx(9.35)  # the median of 8.8 and 9.9
    assert bench.summarise([]).median_s is None


def test_the_last_line_carries_every_figure_and_the_ratio(bench) -> None:
    defaults = bench.SetupSummary(40.0, 9_000.0, 31.25, 29.5, 3, 3)
    fast = bench.SetupSummary(110.0, 33_000.0, 9.64, 8.91, 3, 3, worst_s=150.0, seed_best_s=9.2)
    assert bench.key_values(defaults, fast) == (
        "defaults_median_s=40.0 defaults_lap_s=31.25 fast_median_s=110.0 fast_lap_s=9.64 "
        "fast_worst_s=150.0 best_lap_s=8.91 fast_seed_best_s=9.20 ratio=2.75"
    )
    missed = bench.SetupSummary(None, None, None, 12.0, 0, 3)
    line = bench.key_values(defaults, missed)
    assert "fast_median_s=nan fast_lap_s=nan fast_worst_s=nan best_lap_s=12.00 " in line
    assert line.endswith("fast_seed_best_s=nan ratio=nan")


def test_the_machine_line_names_cores_and_load(bench) -> None:
    text = bench.machine()
    assert " cores, load average " in text and len(text.rsplit("average ", 1)[1].split()) == 3


def test_a_further_mode_adds_its_own_keys_against_the_first_modes_fast_median(bench) -> None:
    defaults = bench.SetupSummary(40.0, 9_000.0, 31.25, 29.5, 3, 3)
    fast = bench.SetupSummary(90.0, 30_000.0, 9.5, 8.5, 3, 3)
    baseline = bench.SetupSummary(120.0, 33_000.0, 9.64, 8.91, 3, 3)
    assert bench.mode_key_values("streams", defaults, fast, baseline) == (
        "streams_defaults_median_s=40.0 streams_defaults_lap_s=31.25 "
        "streams_fast_median_s=90.0 streams_fast_lap_s=9.50 streams_fast_worst_s=nan "
        "streams_ratio=0.75"
    )
    missed = bench.SetupSummary(None, None, None, None, 0, 3)
    assert bench.mode_key_values("streams", defaults, fast, missed).endswith("streams_ratio=nan")


def test_each_mode_trains_as_a_console_job_of_that_mode_would(bench) -> None:
    from training.rl.simulation import launch_local
    from training.rollout.backends import LocalRollouts, StreamRollouts

    local = bench.rollouts("lockstep", "")
    assert local == LocalRollouts(num_workers=2) and local.overlap_evaluation
    assert not bench.rollouts("lockstep", "", beside=False).overlap_evaluation  # the way before
    streams = bench.rollouts("streams", "redis://127.0.0.1:6379/15")
    assert isinstance(streams, StreamRollouts) and streams.workers == 2
    assert streams.launch is launch_local  # local processes, as RACECRAFT_SIMULATION=streams
    assert streams.redis_url == "redis://127.0.0.1:6379/15"


def test_first_seed_lets_one_process_per_seed_run_side_by_side(bench) -> None:
    import argparse

    assert list(bench.seeds_of(argparse.Namespace(seeds=3, first_seed=0))) == [0, 1, 2]
    assert list(bench.seeds_of(argparse.Namespace(seeds=1, first_seed=4))) == [4]


def test_network_is_each_presets_own_or_a_known_name(bench) -> None:
    assert bench.checked_network("") == ""  # each preset's own
    assert bench.checked_network("RACECRAFT_LEAN_CNN") == "RACECRAFT_LEAN_CNN"
    with pytest.raises(SystemExit, match="--network: unknown network 'NOPE'"):
        bench.checked_network("NOPE")


def test_actions_replace_the_racing_presets_own_and_are_checked_as_a_models(bench) -> None:
    import argparse

    four = '[{"steering_angle": 0, "speed": 4}, {"steering_angle": 20, "speed": 2}]'
    actions = bench.checked_actions(four)
    assert actions == (
        {"steering_angle": 0.0, "speed": 4.0},
        {"steering_angle": 20.0, "speed": 2.0},
    )
    setup = bench.racing_setup(argparse.Namespace(actions=actions, lap_limit=10.0))
    assert setup.preset.actions() == list(actions) and setup.lap_limit_s == 10.0
    assert setup.preset.hyperparameters == bench.RACING.hyperparameters  # only the actions
    assert bench.racing_setup(argparse.Namespace(actions=None, lap_limit=10.0)).preset is (
        bench.RACING
    )
    assert bench.checked_actions("") is None
    assert bench.described(actions) == "0° at 4 m/s, 20° at 2 m/s"
    with pytest.raises(SystemExit, match="--actions: action 0: speed 5 is outside 0.1..4 m/s"):
        bench.checked_actions(
            '[{"steering_angle": 0, "speed": 5}, {"steering_angle": 1, "speed": 1}]'
        )
    with pytest.raises(SystemExit, match="--actions: "):
        bench.checked_actions("[{")  # not JSON
    with pytest.raises(SystemExit, match="--actions: give a list of discrete actions"):
        bench.checked_actions(
            '{"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 1, "high": 2}}'
        )


def test_where_failed_evaluations_left_the_track(bench, capsys) -> None:
    assert bench.exit_point(50.0, 2) == (2, 50.0)  # halfway round the second lap
    assert bench.exit_point(130.0, 1) == (1, 100.0)
    assert bench.exit_point(12.0, None) == (0, 12.0)  # a source that does not say the lap
    runs = [
        bench.Run("fast", 0, exits=[(2, 12.0), (2, 18.0), (1, 95.0)]),
        bench.Run("fast", 1, exits=[(3, 40.0), (0, 5.0)]),
        bench.Run("defaults", 0),
    ]
    bench.print_exits(runs)
    out = capsys.readouterr().out
    assert (
        "lockstep fast: 5 evaluations left the track; by lap 1: 1, 2: 2, 3: 1, unknown: 1;" in out
    )
    assert "10-20%: 2" in out and "40-50%: 1" in out and "90-100%: 1" in out
    assert "defaults" not in out  # no failed evaluation, no line
