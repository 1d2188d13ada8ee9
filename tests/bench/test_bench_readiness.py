"""bench/bench_readiness.py's bookkeeping, without training: the completion under the check's
conditions (the baseline apart), the ratios and the last line."""

from __future__ import annotations

import math

import pytest

from tests.bench.loader import load_bench


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_readiness") as module:
        yield module


def cells(clean: int, under: list[int]) -> list[dict]:
    rows = [{"family": "clean", "laps_completed": clean, "laps_attempted": 2}]
    return rows + [{"family": "light", "laps_completed": n, "laps_attempted": 2} for n in under]


def model(bench, world: str, seed: int, *, steps, laps, clean: int, under: list[int]):
    run = bench.bt.Run("fast", seed, seconds=None if steps is None else 10.0, steps=steps,
                       qualifying_laps=[laps] if laps else [])  # fmt: skip
    return bench.Model(world, run, b"", cells=cells(clean, under))


def test_the_last_line_compares_the_randomised_models_with_the_clean_ones(bench):
    models = [
        model(bench, "clean", 0, steps=10_000, laps=[6.0, 6.0, 6.0], clean=2, under=[2, 0, 0]),
        model(bench, "randomised", 0, steps=14_000, laps=[6.3, 6.3, 6.3], clean=2,
              under=[2, 2, 0]),
    ]  # fmt: skip
    assert models[0].laps(baseline=True) == (2, 2) and models[0].laps(baseline=False) == (2, 6)
    line = bench.key_values(models, minutes=8)
    assert line.startswith("completion_ratio=2.00 clean_lap_loss_pct=5.0 steps_loss_pct=40.0 ")
    assert "clean_completion_pct=33.3 randomised_completion_pct=66.7" in line


def test_none_completed_in_the_clean_world_and_missed_goals(bench):
    assert bench.ratio(50.0, 0.0) == math.inf and bench.fmt(math.inf) == "inf"
    assert bench.ratio(0.0, 0.0) is None and bench.loss_pct(None, 5.0) is None
    models = [
        model(bench, "clean", 0, steps=None, laps=[], clean=0, under=[0]),
        model(bench, "randomised", 0, steps=9_000, laps=[6.0], clean=1, under=[1]),
    ]
    assert bench.key_values(models, minutes=1).startswith(
        "completion_ratio=inf clean_lap_loss_pct=nan steps_loss_pct=nan "
    )


def test_the_arguments_default_to_the_goal(bench):
    args = bench.parse_args([])
    assert (args.seeds, args.minutes, args.lap_limit, args.track) == (3, 8.0, 10.0, "reinvent_base")
    assert args.worlds == ["clean", "randomised"] and args.device == "cpu"
    assert args.reward_file is None


def test_reward_file_reaches_the_runs_reward(bench, tmp_path):
    path = tmp_path / "mine.py"
    path.write_text("def reward_function(params):\n    return 1.0\n")
    args = bench.parse_args(["--reward-file", str(path)])
    assert bench.bt.reward_source(bench.RACING, args) == path.read_text()


def test_diagnosis_options_pick_the_families_their_ranges_and_a_step_cap(bench, tmp_path):
    from racing.conditions import ConditionsSpec

    args = bench.parse_args(["--families", "latency", "--widest", "--max-steps", "500"])
    assert (args.families, args.widest, args.max_steps) == (["latency"], True, 500)
    assert bench.parse_args([]).families == ["light", "look", "camera", "car"]
    with bench.outside_world("randomised", ("latency",), widest=True):
        spec = bench.bt.track_spec("reinvent_base", tmp_path, tmp_path, bench.RACING)
    assert spec.conditions == ConditionsSpec.widest(["latency"]).to_dict()
    with bench.outside_world("randomised"):
        spec = bench.bt.track_spec("reinvent_base", tmp_path, tmp_path, bench.RACING)
    assert spec.conditions == ConditionsSpec.default(bench.RECOMMENDED_FAMILIES).to_dict()
    hooks = bench.KeepGoal(bench.bt.Run("fast", 0), 10.0)
    hooks.max_steps = 500
    assert not hooks.should_stop()
    hooks.run.total_steps = 500
    assert hooks.should_stop()


def test_train_steps_trains_on_past_the_goal_and_keeps_the_last_checkpoint(bench):
    assert bench.parse_args(["--train-steps", "40000"]).train_steps == 40000
    assert bench.parse_args([]).train_steps is None
    hooks = bench.KeepGoal(bench.bt.Run("fast", 0), 10.0)
    hooks.train_steps = 1000
    hooks.run.seconds, hooks.run.total_steps = 12.0, 800  # the goal is reached
    assert not hooks.should_stop()  # but it trains on
    hooks.run.total_steps = 1000
    assert hooks.should_stop()
