"""A scripted pure-pursuit driver laps every track three times in a row, both directions,
acting only through the env's normal action interface. Lap times are printed (pytest -s)."""

from __future__ import annotations

import pytest

from racing.controllers import PurePursuitDriver
from racing.env import RacingEnv
from racing.rules import RaceRules
from racing.tracks import TrackCatalog

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4}}
SHIPPED = [info.id for info in TrackCatalog().list() if info.source == "racecraft"]
SHARED = ["reinvent_base", "Oval_track", "2022_reinvent_champ"]  # of DeepRacer's, built in too


def three_laps(track, direction: str, action_space=CONTINUOUS) -> list[float]:
    env = RacingEnv(
        track,
        direction=direction,
        action_space=action_space,
        rules=RaceRules(laps=3),
        start="start_line",
    )
    env.reset(seed=0)
    driver = PurePursuitDriver(env.track)
    info: dict = {}
    for _ in range(20_000):
        action = env.actions.encode(*driver.act(env.pose))
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    assert info["status"] == "lap_complete", (
        f"{track} {direction}: {info['status']} at {info['progress']:.1f}% of lap {info['lap']}"
    )
    assert info["progress"] == 100.0 and info["params"]["progress"] == 100.0  # a full lap
    times = [lap.time_s for lap in info["laps"]]
    print(f"\n{getattr(track, 'track_id', track)} {direction}: laps {[f'{t:.2f}' for t in times]}")
    return times


def test_there_are_three_shipped_tracks():
    assert {"racecraft_summit", "racecraft_oval", "racecraft_technical"} <= set(SHIPPED)


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["ccw", "cw"])
@pytest.mark.parametrize("track_id", SHIPPED)
def test_shipped_tracks(track_id, direction):
    times = three_laps(track_id, direction)
    assert len(times) == 3 and all(t > 1.0 for t in times)


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["ccw", "cw"])
@pytest.mark.parametrize("name", SHARED)
def test_deepracer_tracks(load_shared, name, direction):
    times = three_laps(load_shared(name), direction)
    assert len(times) == 3
    assert max(times) - min(times) < 1.0  # a steady driver laps consistently


@pytest.mark.slow
def test_discrete_actions_can_lap_too(reinvent):
    # DeepRacer-style discrete space: 7 steering levels x 3 speeds.
    from racing.actions import discrete_action_list

    times = three_laps(reinvent, "ccw", action_space=discrete_action_list(30, 7, 2.4, 3))
    assert len(times) == 3
