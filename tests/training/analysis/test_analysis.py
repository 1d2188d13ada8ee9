"""The analysis core (Django-free): sim-trace summaries, chart tables, and reward replay params
that match what the simulator gave the reward function."""

from __future__ import annotations

import numpy as np
import pytest

from racing.env import RacingEnv
from racing.simtrace import to_csv
from racing.tracks import TrackCatalog
from training.analysis import charts
from training.analysis.replay import ReplayError, episode_rows, replay_table, step_params
from training.analysis.synthetic import synthetic_iteration
from training.analysis.trace import Grid, TraceError, parse_simtrace, summarize

TRACK = TrackCatalog([]).load("racecraft_oval")


def _summaries(iterations: int = 3, episodes: int = 12):
    grid = Grid.around(TRACK.bounds())
    out = []
    for it in range(iterations):
        steps = parse_simtrace(synthetic_iteration(TRACK, iteration=it, episodes=episodes,
                                                   num_actions=6, mean_steps=40))  # fmt: skip
        out.append(summarize(steps, iteration=it, grid=grid, num_actions=6,
                             num_waypoints=TRACK.num_waypoints))  # fmt: skip
    return grid, out


def test_summaries_count_episodes_steps_and_times() -> None:
    data = synthetic_iteration(TRACK, iteration=2, episodes=5, num_actions=6, mean_steps=30)
    steps = parse_simtrace(data)
    lines = data.decode().splitlines()[1:]
    assert len(steps) == len(lines)
    grid, _ = _summaries(1)
    s = summarize(steps, iteration=2, grid=grid, num_actions=6, num_waypoints=TRACK.num_waypoints)
    assert s.episodes["episode"].tolist() == [10, 11, 12, 13, 14]
    assert s.episodes["steps"].sum() == len(lines) == s.num_steps
    expected = (s.episodes["steps"] - 1) / 15
    assert np.allclose(s.episodes["time_s"], expected, atol=2e-3)
    assert s.actions.sum() == len(lines) and s.section_actions.sum() == len(lines)


def test_chart_tables() -> None:
    grid, summaries = _summaries()
    progress = charts.progress(summaries, {1: 55.0})
    assert progress["iteration"] == [0, 1, 2] and progress["episodes"] == [12, 12, 12]
    assert progress["eval_progress"] == [None, 55.0, None]
    assert all(0 <= r <= 100 for r in progress["completion_rate"])
    fastest = charts.fastest_laps(summaries, count=5)
    assert fastest["time_s"] == sorted(fastest["time_s"]) and len(fastest["time_s"]) <= 5
    for kind in charts.HEATMAPS:
        heat = charts.heatmap(summaries, grid, kind)
        assert len(heat["values"]) == grid.nx * grid.ny and heat["steps"] > 0
        seen = [v for v in heat["values"] if v is not None]
        assert seen and (kind != "action" or set(seen) <= set(range(6)))
    usage = charts.action_usage(summaries, 6)
    assert all(abs(sum(row) - 100) < 0.1 for row in usage["per_iteration"])
    table = charts.episodes_table(summaries)
    path = charts.episode_path(summaries[1], table["episode"][12])
    assert len(path["x"]) == table["steps"][12]
    csv = charts.to_csv(progress).splitlines()
    assert csv[0].startswith("iteration,episodes,reward") and len(csv) == 4


def test_bad_files_are_refused() -> None:
    with pytest.raises(TraceError):
        parse_simtrace(b"not,a,trace\n1,2,3\n")
    assert len(parse_simtrace(to_csv([]).encode())) == 0


def test_replayed_params_are_what_the_reward_function_saw() -> None:
    seen: list[dict] = []

    def reward(params: dict) -> float:
        seen.append(dict(params))
        return float(params["distance_from_center"])

    env = RacingEnv(TRACK, action_space=[{"steering_angle": 10, "speed": 1.5}] * 2,
                    reward_function=reward)  # fmt: skip
    env.reset(seed=1)
    rows = []
    for _ in range(25):
        _, _, terminated, truncated, info = env.step(0)
        rows.append(info["trace"])
        if terminated or truncated:
            break
    env.close()
    data = to_csv(rows).encode()
    recorded = episode_rows(data, rows[0].episode)
    params = step_params(recorded, TRACK)
    assert len(params) == len(seen)
    for old, new in zip(seen, params, strict=True):
        assert new["closest_waypoints"] == old["closest_waypoints"]
        assert new["distance_from_center"] == pytest.approx(old["distance_from_center"], abs=2e-3)
        assert new["is_left_of_center"] == old["is_left_of_center"]
        assert new["heading"] == pytest.approx(old["heading"], abs=1e-3)
        assert new["speed"] == old["speed"] and new["steps"] == old["steps"]
        assert new["progress"] == pytest.approx(old["progress"], abs=1e-3)
        assert new["all_wheels_on_track"] == old["all_wheels_on_track"]
    table = replay_table(recorded, [1.0] * len(recorded))
    assert table["new_total"] == len(recorded)
    assert table["old_total"] == pytest.approx(
        sum(p["distance_from_center"] for p in seen), abs=0.01
    )
    with pytest.raises(ReplayError):
        episode_rows(data, 99)
