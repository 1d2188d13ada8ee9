"""The training log: interleaved cars become DeepRacer's iterations of E whole episodes."""

from __future__ import annotations

import pytest

from racing.simtrace import TraceRow
from training.interchange.logbook import TrainingLog


def _row(episode: int, step: int, *, done: bool, t: float) -> list:
    return list(
        TraceRow(
            episode=episode, steps=step, x=1.0, y=2.0, yaw=0.0, steer=0.0, throttle=1.0,
            action=1, reward=1.0, done=done, all_wheels_on_track=True, progress=10.0 * step,
            closest_waypoint=step, track_len=17.7, tstamp=t,
            episode_status="prepare" if step == 1 else ("off_track" if done else "in_progress"),
            pause_duration=0.0, obstacle_crash_counter=0, wall_clock=1.0,
        )
    )  # fmt: skip


def _drive(cars: dict[int, list[int]]) -> tuple[list[list], list[dict]]:
    """Rows of cars driving side by side (``cars``: car id -> its episodes' lengths) and their
    entries, in the order a vectorised env reports them."""
    rows, entries = [], []
    state = {car: [0, 0, 0.0] for car in cars}  # episode index, step, clock
    while any(state[c][0] < len(lengths) for c, lengths in cars.items()):
        for car, lengths in cars.items():
            ep, step, clock = state[car]
            if ep >= len(lengths):
                continue
            step += 1
            done = step == lengths[ep]
            rows.append([*_row(ep, step, done=done, t=clock + 0.1 * (step - 1)), car])
            if done:
                entries.append({"car": car, "env_episode": ep, "reward_score": step,
                                "elapsed_time_in_milliseconds": 100 * step})  # fmt: skip
                state[car] = [ep + 1, 0, clock + 0.1 * step]
            else:
                state[car] = [ep, step, clock]
    return rows, entries


def test_interleaved_cars_become_whole_numbered_episodes() -> None:
    rows, entries = _drive({11: [3, 5, 2], 22: [4, 4], 33: [6, 1, 2]})
    log = TrainingLog(3)
    half = len(rows) // 2
    log.add_rows(rows[:half])  # an update in the middle: episodes straddle it
    for e in entries:
        log.add_entry(e)
    first = log.take()
    log.add_rows(rows[half:])
    rest = log.take(final=True)
    iterations = first + rest
    assert [it.number for it in iterations] == [0, 1, 2]
    assert [len(it.episodes) for it in iterations] == [3, 3, 2]
    numbered = [e for it in iterations for e in it.episodes]
    assert [e.entry["episode"] for e in numbered] == list(range(1, 9))
    assert [e.entry["trial"] for e in numbered] == [1, 2, 3, 1, 2, 3, 1, 2]
    for i, episode in enumerate(numbered):
        assert {row.episode for row in episode.rows} == {i}
        assert [row.steps for row in episode.rows] == list(range(1, len(episode.rows) + 1))
        assert episode.rows[0].episode_status == "prepare" and episode.rows[-1].done
        assert episode.entry["reward_score"] == len(episode.rows)
    assert log.logged == 8 and log.iterations_logged == 3


def test_csv_keeps_each_episode_together() -> None:
    rows, entries = _drive({1: [2, 2], 2: [3]})
    log = TrainingLog(5)
    log.add_rows(rows)
    for e in entries:
        log.add_entry(e)
    assert log.take() == []  # fewer than E finished: nothing to write yet
    (it,) = log.take(final=True)
    lines = it.simtrace_csv().splitlines()
    assert lines[0].startswith("episode,steps,X,Y")
    assert [int(line.split(",")[0]) for line in lines[1:]] == [0, 0, 1, 1, 1, 2, 2]


def test_malformed_rows_and_entries_are_dropped() -> None:
    log = TrainingLog(1)
    good = [*_row(0, 1, done=True, t=0.0), 7]
    log.add_rows([["junk"], [*_row(0, 1, done=True, t=0.0)], "x", good])  # type: ignore[list-item]
    log.add_entry("not a dict")  # type: ignore[arg-type]
    log.add_entry({"car": 7, "env_episode": 0})
    (it,) = log.take()
    assert len(it.episodes) == 1 and len(it.episodes[0].rows) == 1


def test_cars_of_an_env_runner_log_deepracer_times() -> None:
    """Real cars (EnvRunner): each logged episode starts with a prepare row stamped at its start
    on the car's running clock, so last - first tstamp is the entry's elapsed time."""
    import numpy as np

    from training.rollout.envs import EnvRunner, EnvSpec

    spec = EnvSpec(track="racecraft_oval", action_space=[{"steering_angle": a, "speed": 2.0}
                                                         for a in (-30, 0, 30)])  # fmt: skip
    runner = EnvRunner([spec.make(), spec.make()])
    runner.reset([1, 2])
    log = TrainingLog(2)
    rng = np.random.default_rng(0)
    try:
        while log.logged + log.queued < 6:
            _, _, _, infos = runner.step(rng.integers(0, 3, 2))
            log.add_rows([info["trace"] for info in infos])
            for info in infos:
                if info.get("episode_entry"):
                    log.add_entry(info["episode_entry"])
    finally:
        runner.close()
    episodes = [e for it in log.take() for e in it.episodes]
    assert len(episodes) >= 4
    clocks: dict[int, float] = {}
    for e in episodes:
        first, last = e.rows[0], e.rows[-1]
        assert first.episode_status == "prepare" or len(e.rows) == 1
        assert last.tstamp - first.tstamp == pytest.approx(
            e.entry["elapsed_time_in_milliseconds"] / 1000, abs=2e-3
        )
        assert e.entry["start_time"] == round(first.tstamp * 1000)
        car = e.entry["car"]
        assert first.tstamp >= clocks.get(car, 0.0) - 1e-9  # a car's clock never restarts
        clocks[car] = last.tstamp


def test_continuous_actions_travel_as_simapps_text() -> None:
    """A continuous car's row is JSON scalars (what a sandboxed worker may send) and its
    action is written as SimApp writes it, ``[steer speed]``."""
    import json

    import numpy as np

    from training.rollout.envs import EnvRunner, EnvSpec
    from training.sandbox import checked

    spec = EnvSpec(track="racecraft_oval", action_space={
        "steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2}})  # fmt: skip
    runner = EnvRunner([spec.make()])
    runner.reset([1])
    try:
        _, _, _, infos = runner.step(np.array([[30.0, 2.0]], dtype=np.float32))
    finally:
        runner.close()
    row = json.loads(json.dumps(infos[0]["trace"]))
    assert checked.scalars(row, "trace") == row
    assert row[7] == "[30.00 2.00]"
    assert TraceRow(*row[:19]).format().split(",")[7] == "[30.00 2.00]"
