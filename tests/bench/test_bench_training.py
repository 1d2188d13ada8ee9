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


def test_lagged_rollout_is_an_experiments_switch_off_by_default(bench, monkeypatch) -> None:
    """``--lagged-rollout`` reaches the run's TrainingConfig; without it (bench_stalls.py and
    bench_readiness.py's arguments have no such attribute) the console's own lockstep loop."""
    import argparse

    seen = []

    class Stop(Exception):
        pass

    def config(**kwargs):
        seen.append(kwargs["lagged_rollout"])
        raise Stop

    monkeypatch.setattr(bench, "TrainingConfig", config)
    monkeypatch.setattr(bench, "track_spec", lambda *a, **k: None)
    common = dict(actions="", track="reinvent_base", tracks_dir=None, network="", overrides={},
                  minutes=1.0, evaluate_after=False, trainer_samples=False, device="cpu",
                  lap_limit=10.0)  # fmt: skip
    for extra in ({}, {"lagged_rollout": False}, {"lagged_rollout": True}):
        args = argparse.Namespace(**common, **extra)
        with pytest.raises(Stop):
            bench.run_one(bench.racing_setup(args), 0, args, None)
    assert seen == [False, False, True]


def test_first_seed_lets_one_process_per_seed_run_side_by_side(bench) -> None:
    import argparse

    assert list(bench.seeds_of(argparse.Namespace(seeds=3, first_seed=0))) == [0, 1, 2]
    assert list(bench.seeds_of(argparse.Namespace(seeds=1, first_seed=4))) == [4]


def test_network_is_each_presets_own_or_a_known_name(bench) -> None:
    assert bench.checked_network("") == ""  # each preset's own
    assert bench.checked_network("RACECRAFT_LEAN_CNN") == "RACECRAFT_LEAN_CNN"
    with pytest.raises(SystemExit, match="--network: unknown network 'NOPE'"):
        bench.checked_network("NOPE")


def test_reward_example_replaces_the_racing_presets_reward_and_nothing_else(bench) -> None:
    import argparse

    args = argparse.Namespace(
        actions=None, lap_limit=10.0, reward_example="speed_along_track_bends"
    )
    preset = bench.racing_setup(args).preset
    assert preset.reward_example == "speed_along_track_bends"
    assert (preset.action_space, preset.hyperparameters) == (
        bench.RACING.action_space,
        bench.RACING.hyperparameters,
    )
    args.reward_example = ""
    assert bench.racing_setup(args).preset is bench.RACING


def test_reward_file_trains_the_racing_preset_with_its_text_and_leaves_the_defaults_theirs(
    bench, tmp_path
) -> None:
    import argparse

    from training.rewards.examples import example_source

    path = tmp_path / "mine.py"
    path.write_text("def reward_function(params):\n    return 1.0\n")
    args = argparse.Namespace(reward_file=path)
    assert bench.reward_source(bench.RACING, args) == path.read_text()
    assert bench.reward_source(bench.DEEPRACER_DEFAULTS, args) == example_source(
        "follow_center_line"
    )
    assert bench.reward_source(bench.RACING, argparse.Namespace()) == example_source(
        "speed_along_track"
    )
    args.reward_file = tmp_path / "missing.py"
    with pytest.raises(SystemExit, match="--reward-file: .*missing.py"):
        bench.reward_source(bench.RACING, args)


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


# ------------------------------------------------------------------------------ --suite
def test_each_suite_track_gets_a_lap_limit_scaled_from_reinvent_2018s_by_its_length(bench) -> None:
    lengths = {t: bench.track_length(t) for t in bench.SUITE_TRACKS}
    assert lengths["reinvent_base"] == pytest.approx(17.71)
    assert all(17 < length < 77 for length in lengths.values())
    assert [t for t, length in lengths.items() if length >= 40] == ["2022_may_open", "2022_may_pro"]
    ref = lengths["reinvent_base"]
    limits = {t: bench.lap_limit_for(length, ref, 10.0) for t, length in lengths.items()}
    assert limits == {
        "reinvent_base": 10.0,  # the reference keeps --lap-limit
        "Tokyo_Training_track": 12.8,
        "2022_may_open": 26.0,
        "2022_may_pro": 36.1,
        "2022_reinvent_champ": 18.8,
    }
    assert bench.lap_limit_for(ref, ref, 8.0) == 8.0  # --lap-limit scales them all
    formula = bench.lap_limit_formula(ref, 10.0, 3.5)
    assert formula.startswith("lap limit = length / 1.771 m/s, rounded to 0.1 s")
    assert "10.0 s for 17.71 m" in formula and "51% of the racing preset's top speed" in formula
    with pytest.raises(SystemExit, match="--suite-tracks: no track 'nope'"):
        bench.track_length("nope")


def test_a_missed_seed_is_a_lower_bound_that_leaves_the_median_exact_only_above_it(bench) -> None:
    m = bench.censored_median
    assert m([(100.0, True), (140.0, True), (360.0, False)]) == bench.Bound(140.0)
    assert m([(100.0, True), (360.0, False), (360.0, False)]) == bench.Bound(360.0, exact=False)
    # 40,000 steps when capped, below a seed that reached at 50,000: the median is unknown
    assert m([(30_000.0, True), (50_000.0, True), (40_000.0, False)]).exact is False
    assert m([]) == bench.Bound(None)
    assert bench.censored_max([(1.0, True), (2.0, True)]) == bench.Bound(2.0)
    assert bench.censored_max([(1.0, True), (2.0, False)]) == bench.Bound(2.0, exact=False)
    assert bench.Bound(12345.0, exact=False).text(0, thousands=True) == ">12,345"
    assert bench.Bound(360.0, exact=False).key() == "nan" and bench.Bound(9.25).key() == "9.2"


def suite_runs(bench):
    def r(track, setup, seed, seconds, steps, total, wall=0.0, best=None, laps=()):
        return bench.Run(setup, seed, seconds=seconds, steps=steps, total_steps=total,
                         wall_s=wall, best_lap_s=best, track=track,
                         qualifying_laps=[list(ev) for ev in laps])  # fmt: skip

    return [
        r("reinvent_base", "fast", 0, 60.0, 12_000, 12_000, best=5.4, laps=[[6.0] * 3] * 3),
        r("reinvent_base", "fast", 1, 50.0, 10_000, 10_000, best=5.6, laps=[[5.8] * 3] * 3),
        r("reinvent_base", "fast", 2, 100.0, 21_000, 21_000, best=5.5, laps=[[6.2] * 3] * 3),
        r("2022_may_pro", "fast", 0, None, None, 80_000, wall=361.0, best=30.0),
        r("2022_may_pro", "fast", 1, 300.0, 70_000, 70_000, best=29.0, laps=[[33.0] * 3] * 3),
        r("2022_may_pro", "fast", 2, None, None, 75_000, wall=362.0),
        r("reinvent_base", "defaults", 0, 20.0, 5_000, 5_000),
    ]


def test_the_suites_figures_per_track_and_its_last_line_against_a_baseline(bench) -> None:
    runs = suite_runs(bench)
    s = bench.summarise_track("reinvent_base", "fast", runs)
    assert (s.runs, s.reached, s.median_s, s.worst_s) == (
        3,
        3,
        bench.Bound(60.0),
        bench.Bound(100.0),
    )
    assert (s.median_steps, s.worst_steps) == (bench.Bound(12_000.0), bench.Bound(21_000.0))
    assert (s.best_lap_s, s.lap_s) == (5.4, 6.0)
    pro = bench.summarise_track("2022_may_pro", "fast", runs)
    assert pro.reached == 1 and pro.median_s == bench.Bound(361.0, exact=False)
    assert pro.median_steps == bench.Bound(75_000.0, exact=False) and pro.lap_s == 33.0
    defaults = {"reinvent_base": bench.summarise_track("reinvent_base", "defaults", runs)}
    fast = {"reinvent_base": s, "2022_may_pro": pro}
    tracks = ["reinvent_base", "2022_may_pro"]
    line = bench.suite_key_values(tracks, fast, defaults)
    assert line.startswith(
        "suite_reinvent_base_median_s=60.0 suite_reinvent_base_worst_s=100.0 "
        "suite_reinvent_base_steps=12000 suite_reinvent_base_worst_steps=21000 "
        "suite_reinvent_base_reached=3 suite_reinvent_base_best_lap_s=5.40 "
        "suite_reinvent_base_lap_s=6.00 suite_reinvent_base_defaults_median_s=20.0 "
        "suite_2022_may_pro_median_s=nan "
    )
    assert "suite_2022_may_pro_reached=1 " in line
    assert line.endswith("suite_max_spread=1.67")  # 100 s against 60 s; the Pro track unknown
    baseline = {"reinvent_base": {"median_s": {"value": 120.0, "exact": True}},
                "2022_may_pro": {"median_s": {"value": 360.5, "exact": False}}}  # fmt: skip
    pro_now = bench.TrackSummary("2022_may_pro", "fast", 3, 3, bench.Bound(180.0),
                                 bench.Bound(200.0), bench.Bound(40_000.0),
                                 bench.Bound(45_000.0), 25.0, 28.0)  # fmt: skip
    line = bench.suite_key_values(tracks, {**fast, "2022_may_pro": pro_now}, {}, baseline)
    assert "suite_reinvent_base_ratio=0.50 " in line
    assert "suite_2022_may_pro_ratio_at_most=0.50 " in line  # the baseline's median: >360.5 s
    assert line.endswith("suite_median_ratio=0.50 suite_worst_ratio=0.50 suite_max_spread=1.67")


def test_suite_runs_the_racing_preset_first_then_the_defaults_where_their_probe_finishes(
    bench, monkeypatch, capsys, tmp_path
) -> None:
    import argparse

    import torch

    trained = []

    def run_one(setup, seed, args, scratch, *, mode, redis_url):
        trained.append((setup.name, args.track, seed, setup.lap_limit_s, args.minutes))
        done = setup.name == "fast" or args.track == "reinvent_base"
        laps = [[setup.lap_limit_s or 30.0] * 3] * 3 if done else []
        return bench.Run(setup.name, seed, seconds=10.0 + seed if done else None,
                         steps=1000 * (seed + 1) if done else None, total_steps=1000 * (seed + 1),
                         wall_s=60.0 * args.minutes, qualifying_laps=laps)  # fmt: skip

    monkeypatch.setattr(bench, "run_one", run_one)
    monkeypatch.setattr("sys.argv", ["bench_training.py", "--suite"])
    out_json = tmp_path / "suite.json"
    args = argparse.Namespace(
        suite_tracks=["reinvent_base", "Tokyo_Training_track"], setups=["defaults", "fast"],
        seeds=2, first_seed=0, minutes=6.0, defaults_minutes=3.0, lap_limit=10.0, actions=None,
        tracks_dir=bench.SHARED, redis_url="", json=out_json, baseline=None,
    )  # fmt: skip
    bench.suite_main(args, torch.device("cpu"), ["lockstep"])
    assert trained == [
        ("fast", "reinvent_base", 0, 10.0, 6.0),
        ("fast", "reinvent_base", 1, 10.0, 6.0),
        ("fast", "Tokyo_Training_track", 0, 12.8, 6.0),
        ("fast", "Tokyo_Training_track", 1, 12.8, 6.0),
        ("defaults", "reinvent_base", 0, None, 3.0),
        ("defaults", "reinvent_base", 1, None, 3.0),
        ("defaults", "Tokyo_Training_track", 0, None, 3.0),  # the probe misses: no seed 1
    ]
    out = capsys.readouterr().out
    assert (
        "lap limit = length / 1.771 m/s" in out
        and "Tokyo_Training_track: 22.63 m, lap limit 12.8 s" in out
    )
    assert "defaults on Tokyo_Training_track: the probe seed 0 missed the goal within 3 min" in out
    assert "Tokyo_Training_track    22.63m  12.8s  fast          2/2         1,500     2,000" in out
    assert (
        "Tokyo_Training_track    22.63m    any  defaults      0/1        >1,000    >1,000    >180.0"
        in out
    )
    last = out.strip().splitlines()[-1]
    assert last.startswith("suite_reinvent_base_median_s=10.5 ") and "=nan" in last

    args.baseline, args.json = out_json, None  # the same figures again: every ratio 1
    bench.suite_main(args, torch.device("cpu"), ["lockstep"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "suite_tokyo_training_track_ratio=1.00 " in last and "suite_median_ratio=1.00 " in last
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(SystemExit, match="--baseline .*bad.json: not a --suite --json file"):
        bench.read_baseline(tmp_path / "bad.json")


def test_max_steps_stops_a_run_that_has_not_reached_the_goal_as_a_lower_bound(bench) -> None:
    r = bench.Run("fast", 0)
    hooks = bench.UntilGoal(r, None)
    r.total_steps = 30_000
    assert not hooks.should_stop()  # no --max-steps: only the goal (or --minutes) stops it
    hooks.max_steps = 30_000
    assert hooks.should_stop() and r.steps is None  # stopped, the goal not reached
    hooks.max_steps, r.total_steps = 40_000, 12_000
    assert not hooks.should_stop()


def test_ready_evaluates_as_the_console_and_stops_by_the_loops_own_condition(bench) -> None:
    """``--ready N``: the console's evaluation (TrainingConfig's defaults, as a job gets them)
    and its "stop when ready" condition; without it, the bench's one 3-lap episode from the
    start line."""
    from training.rl.runner import TrainingConfig

    console = TrainingConfig(spec=None)
    assert bench.evaluation_settings(3) == {
        "eval_episodes": console.eval_episodes, "eval_laps": console.eval_laps,
        "eval_from_start_line": console.eval_from_start_line, "stop_when_ready": 3,
    }  # fmt: skip
    assert (console.eval_episodes, console.eval_laps, console.eval_from_start_line) == (5, 1, False)
    assert bench.evaluation_settings(0) == {"eval_episodes": 1, "eval_laps": bench.EVAL_LAPS,
                                            "eval_from_start_line": True}  # fmt: skip
