"""The race runner (training/rl/race.py): policies in, results, sim-traces and the broadcast
MP4 out; a car that cannot race or whose policy fails is out and the race goes on."""

from __future__ import annotations

import io

import av
import pytest

from racing.headtohead import Racer
from racing.rules import Status
from racing.tracks import TrackCatalog
from training.rl.race import RaceEntry, RaceError, RaceSettings, run_race

SETTINGS = RaceSettings(laps=1, time_limit_s=12.0, record_video=False)


def constant(steering: float, speed: float) -> Racer:
    return Racer(action_space=[{"steering_angle": steering, "speed": speed}] * 2)


@pytest.fixture(scope="module")
def oval():
    return TrackCatalog([]).load("racecraft_oval").in_direction("native")


def entries(**overrides) -> list[RaceEntry]:
    made = [RaceEntry(key=1, name="one", racer=constant(0, 1.0), policy=lambda obs: 0),
            RaceEntry(key=2, name="two", racer=constant(3, 0.6), policy=lambda obs: 1)]  # fmt: skip
    for index, values in overrides.items():
        for name, value in values.items():
            setattr(made[int(index[1:])], name, value)
    return made


def test_a_race_reports_every_car_and_the_same_race_reports_the_same(oval):
    first = run_race(entries(), oval, SETTINGS).to_json()
    assert run_race(entries(), oval, SETTINGS).to_json() == first
    assert first["steps"] == 180 and first["race_time_s"] == pytest.approx(12.0)
    assert sorted(car["position"] for car in first["cars"]) == [1, 2]
    assert {car["model"] for car in first["cars"]} == {1, 2}
    car = first["cars"][0]
    assert set(car) >= {"model", "name", "position", "finished", "lap_times_s", "total_time_s",
                        "progress", "off_track", "crashes", "resets"}  # fmt: skip
    assert first["winner"] == car["model"] and car["progress"] > first["cars"][1]["progress"]


def test_a_failing_policy_puts_its_car_out_and_the_race_goes_on(oval):
    calls = {"n": 0}

    def breaks_at_step_20(obs):
        calls["n"] += 1
        if calls["n"] == 20:
            raise RuntimeError("weights on fire")
        return 0

    report = run_race(entries(e0={"policy": breaks_at_step_20}), oval, SETTINGS)
    out = next(car for car in report.cars if car.key == 1)
    assert out.status == "out" and out.position == 2
    assert out.reason == "its policy failed: RuntimeError: weights on fire"
    assert out.rows and len(out.rows) == 19  # it drove 19 steps, then it was out
    running = next(car for car in report.cars if car.key == 2)
    assert running.status == "time_up"
    # It drove every step of the 12 s but the 5 s (75 steps) it stood after each penalty.
    assert len(running.rows) == 180 - 75 * (running.off_track + running.crashes)
    assert report.winner is running


def test_a_car_that_cannot_race_is_out_from_the_start(oval):
    report = run_race(entries(e1={"policy": None, "unavailable": "its checkpoint is missing"}),
                      oval, SETTINGS)  # fmt: skip
    out = next(car for car in report.cars if car.key == 2)
    assert (out.status, out.reason, out.progress, out.rows) == (
        "out",
        "its checkpoint is missing",
        0.0,
        [],
    )
    assert report.to_json()["winner"] == 1


def test_the_sim_trace_has_one_episode_a_lap_as_an_evaluation_writes_it(oval):
    report = run_race(entries(), oval, RaceSettings(laps=1, time_limit_s=12.0,
                                                    record_video=False))  # fmt: skip
    rows = report.cars[0].rows
    assert rows[0][0] == 0 and rows[0][1] == 1  # episode 0, step 1
    assert rows[0][15] == Status.PREPARE.value
    assert [row[1] for row in rows[:5]] == [1, 2, 3, 4, 5]
    statuses = {row[15] for row in rows}
    assert statuses <= {s.value for s in Status}


def test_the_broadcast_video_has_a_frame_a_step_at_15_fps(oval):
    report = run_race(entries(), oval, RaceSettings(laps=1, time_limit_s=10.0))
    assert report.video_mp4
    with av.open(io.BytesIO(report.video_mp4)) as container:
        stream = container.streams.video[0]
        frames = list(container.decode(stream))
        assert (stream.width, stream.height) == (1280, 720)
        assert stream.average_rate == 15
    assert len(frames) == report.steps == 150


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"laps": 0}, "1 to 10 laps"),
        ({"laps": 11}, "1 to 10 laps"),
        ({"crash_penalty_s": 61}, "crash penalty s must be 0-60"),
        ({"time_limit_s": 5}, "10-3600 seconds"),
        ({"round": -1}, "cannot be negative"),
    ],
)
def test_race_settings_refuse_what_a_race_does_not_allow(kwargs, message):
    with pytest.raises(RaceError, match=message):
        RaceSettings(**kwargs)
