"""The analysis core (Django-free): sim-trace summaries, chart tables, and reward replay params
that match what the simulator gave the reward function."""

from __future__ import annotations

import numpy as np
import pytest

from racing.env import RacingEnv
from racing.simtrace import SIMTRACE_COLUMNS, TraceRow, to_csv
from racing.tracks import TrackCatalog
from training.analysis import charts
from training.analysis.actions import ActionBins
from training.analysis.replay import ReplayError, episode_rows, replay_table, step_params
from training.analysis.summary import RunSummary
from training.analysis.synthetic import synthetic_iteration
from training.analysis.trace import Grid, TraceError, parse_simtrace, summarize
from training.rollout.envs import EpisodeBook

TRACK = TrackCatalog([]).load("racecraft_oval")
ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1, 2)]
BINS = ActionBins.for_action_space(ACTIONS)


def _summaries(iterations: int = 3, episodes: int = 12):
    grid = Grid.around(TRACK.bounds())
    out = []
    for it in range(iterations):
        steps = parse_simtrace(synthetic_iteration(TRACK, iteration=it, episodes=episodes,
                                                   num_actions=6, mean_steps=40))  # fmt: skip
        out.append(summarize(steps, iteration=it, grid=grid, bins=BINS,
                             num_waypoints=TRACK.num_waypoints))  # fmt: skip
    return grid, out


def _run(iterations: int = 3, episodes: int = 12) -> RunSummary:
    grid, parts = _summaries(iterations, episodes)
    return RunSummary.empty(grid, BINS, TRACK.num_waypoints).merged(parts)


def test_summaries_count_episodes_steps_and_times() -> None:
    data = synthetic_iteration(TRACK, iteration=2, episodes=5, num_actions=6, mean_steps=30)
    steps = parse_simtrace(data)
    lines = data.decode().splitlines()[1:]
    assert len(steps) == len(lines)
    grid, _ = _summaries(1)
    s = summarize(steps, iteration=2, grid=grid, bins=BINS, num_waypoints=TRACK.num_waypoints)
    assert s.episodes["episode"].tolist() == [10, 11, 12, 13, 14]
    assert s.episodes["steps"].sum() == len(lines) == s.num_steps
    expected = (s.episodes["steps"] - 1) / 15
    assert np.allclose(s.episodes["time_s"], expected, atol=2e-3)
    assert s.actions.sum() == len(lines) and s.section_actions.sum() == len(lines)


def test_chart_tables() -> None:
    grid, parts = _summaries()
    run = RunSummary.empty(grid, BINS, TRACK.num_waypoints).merged(parts)
    progress = charts.progress(run, {1: 55.0})
    assert progress["iteration"] == [0, 1, 2] and progress["episodes"] == [12, 12, 12]
    assert progress["eval_progress"] == [None, 55.0, None]
    assert all(0 <= r <= 100 for r in progress["completion_rate"])
    for part, reward, rate in zip(parts, progress["reward"], progress["completion_rate"],
                                  strict=True):  # fmt: skip
        assert reward == pytest.approx(part.episodes["reward"].mean(), abs=1e-3)
        assert rate == pytest.approx(100 * part.episodes["completed"].mean(), abs=0.01)
    done = parts[0].episodes["time_s"][parts[0].episodes["completed"]]
    assert progress["lap_time"][0] == pytest.approx(done.mean(), abs=1e-3)
    if len(done) > 1:
        assert progress["lap_time_std"][0] == pytest.approx(done.std(), abs=1e-3)
    fastest = charts.fastest_laps(run, count=5)
    assert fastest["time_s"] == sorted(fastest["time_s"]) and len(fastest["time_s"]) <= 5
    for kind in charts.HEATMAPS:
        heat = charts.heatmap(run, kind)
        assert len(heat["values"]) == grid.nx * grid.ny and heat["steps"] > 0
        seen = [v for v in heat["values"] if v is not None]
        assert seen and (kind != "action" or set(seen) <= set(range(6)))
    usage = charts.action_usage(run)
    assert all(abs(sum(row) - 100) < 0.1 for row in usage["per_iteration"])
    table = charts.episodes_table(run)
    assert table["episode"] == list(range(36)) and table["iteration"] == [0] * 12 + [1] * 12 + [
        2] * 12  # fmt: skip
    steps = parse_simtrace(synthetic_iteration(TRACK, iteration=1, episodes=12, num_actions=6,
                                               mean_steps=40))  # fmt: skip
    path = charts.episode_path(steps, table["episode"][12])
    assert len(path["x"]) == table["steps"][12] and path["steps"] == sorted(path["steps"])
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
        assert new["sim_time"] == pytest.approx(old["sim_time"], abs=1e-3)
    table = replay_table(recorded, [1.0] * len(recorded))
    assert table["new_total"] == len(recorded)
    assert table["old_total"] == pytest.approx(
        sum(p["distance_from_center"] for p in seen), abs=0.01
    )
    with pytest.raises(ReplayError):
        episode_rows(data, 99)


def test_replayed_sim_time_is_the_recorded_clock_from_the_episode_start() -> None:
    """Through the rows as training logs them (EpisodeBook: the car's clock runs on across
    episodes, the first row is ``prepare`` stamped at the start): the second episode's
    replayed ``sim_time`` is what its reward saw, not the car's clock and not from 0."""
    seen: list[dict] = []

    def reward(params: dict) -> float:
        seen.append(dict(params))
        return 1.0

    env = RacingEnv(TRACK, action_space=[{"steering_angle": 30, "speed": 4.0}] * 2,
                    reward_function=reward)  # fmt: skip
    book = EpisodeBook(env)
    logged: list[list] = []
    for episode in range(2):
        env.reset(seed=1 if episode == 0 else None)
        book.reset()
        seen.clear()
        for _ in range(300):
            _, r, terminated, truncated, info = env.step(0)
            done = terminated or truncated
            logged.append(book.trace(info["trace"], done))
            book.step(r, info, done)
            if done:
                break
    env.close()
    rows = [TraceRow(*raw[: len(SIMTRACE_COLUMNS)]) for raw in logged]
    first, second = ([row for row in rows if row.episode == n] for n in (0, 1))
    assert second[0].episode_status == "prepare"
    assert second[0].tstamp == pytest.approx(first[-1].tstamp)  # the car's running clock
    assert second[0].tstamp > 0
    recorded = episode_rows(to_csv(rows).encode(), 1)
    assert [float(r["tstamp"]) for r in recorded] == pytest.approx(
        [row.tstamp for row in second], abs=1e-3)  # fmt: skip
    replayed = [p["sim_time"] for p in step_params(recorded, TRACK)]
    assert replayed == pytest.approx([p["sim_time"] for p in seen], abs=2e-3)
    assert replayed[0] == pytest.approx(1 / 15, abs=1e-3) and len(replayed) > 3
