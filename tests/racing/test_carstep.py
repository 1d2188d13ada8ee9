"""One car, one step (racing/carstep.py): RacingEnv and HeadToHeadRace drive a car the same way."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racing import carstep
from racing.actions import ActionSpec
from racing.car import MAX_SPEED, MIN_SPEED, CarSim
from racing.carstep import CarOnTrack
from racing.controllers import PurePursuitDriver
from racing.env import RacingEnv
from racing.headtohead import HeadToHeadRace, Racer
from racing.objects import KIND_BOX, KIND_RACER, Lanes, RaceObject
from racing.race import LANE_INNER
from racing.rules import RaceRules, RaceTracker, Status
from racing.tracks import TrackCatalog
from racing.world import Spot

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.3, "high": 4.0}}
SAME = ("steps", "steer", "throttle", "action", "done", "all_wheels_on_track", "progress",
        "closest_waypoint", "tstamp", "episode_status", "pause_duration")  # fmt: skip
"""Trace columns that the env and the race write alike (not episode, reward, a respawn's X/Y)."""
RULES = RaceRules(laps=1, resets=10, off_track_penalty_s=2.0, time_limit_s=120.0)


@pytest.fixture(scope="module")
def oval():
    return TrackCatalog([]).load("racecraft_oval").in_direction("native")


def env_drive(oval, steps: int = 160) -> tuple[list, list]:
    """A car on the env: pure pursuit, then 25 steps hard left (off track and a respawn), then
    pure pursuit again; the actions it chose and every step's info."""
    env = RacingEnv(oval, action_space=CONTINUOUS, rules=RULES, start="start_line")
    env.reset(seed=0, options={"offset": Lanes(oval).offset(0.0, LANE_INNER)})
    driver = PurePursuitDriver(oval, max_speed=2.0)
    actions, infos = [], []
    for i in range(steps):
        action = [30.0, 2.0] if 40 <= i < 65 else list(driver.act(env.pose))
        actions.append(action)
        infos.append(env.step(np.asarray(action, dtype=np.float32))[4])
    env.close()
    return actions, infos


def test_the_env_and_a_one_car_race_drive_the_same_car_identically(oval):
    actions, infos = env_drive(oval)
    race = HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS)], rules=RULES)
    race.reset()
    outcomes = []
    for action in actions:  # the race clock runs on while the car sits out a penalty
        while race.observations()[0] is None:
            assert race.step([None]) == [None]
        outcomes.append(race.step([np.asarray(action, dtype=np.float32)])[0])
    race.close()
    resets = [i for i, info in enumerate(infos) if info["reset"]]
    assert resets, "the hard left turn must take the car off track and respawn it"
    assert infos[resets[0]]["status"] == "off_track"
    for info, outcome in zip(infos, outcomes, strict=True):
        assert outcome is not None and outcome.status.value == info["status"]
        env_row, race_row = info["trace"], outcome.trace
        assert [getattr(env_row, f) for f in SAME] == [getattr(race_row, f) for f in SAME]
        # One rule for a respawn's row too: where the car was judged, on both paths.
        assert (env_row.x, env_row.y, env_row.yaw) == (race_row.x, race_row.y, race_row.yaw)
    assert race.cars[0].speeds == [1.0] * len(outcomes)


def test_an_off_track_reset_puts_the_car_at_rest_on_the_nearer_lane_at_the_same_point(oval):
    _, infos = env_drive(oval)
    first = next(i for i, info in enumerate(infos) if info["reset"])
    before, info = infos[first - 1], infos[first]
    row = info["trace"]
    assert info["params"]["all_wheels_on_track"] is False and row.all_wheels_on_track is False
    assert row.pause_duration == 2.0 and info["penalty_s"] == 2.0
    # The clock jumps by the step and the penalty: 1/15 s + 2 s.
    assert row.tstamp == pytest.approx(before["trace"].tstamp + 1 / 15 + 2.0)
    assert row.progress == pytest.approx(info["progress"])  # no progress lost or gained
    # The row says where the car was judged: off the track, at params' reported point.
    assert (row.x, row.y) == (info["params"]["x"], info["params"]["y"])
    # The next step starts from the nearer lane at the same centre-line point.
    after = infos[first + 1]["params"]
    assert after["distance_from_center"] == pytest.approx(
        info["params"]["track_width"] / 4, abs=0.05
    )
    assert after["projection_distance"] == pytest.approx(
        info["params"]["projection_distance"], abs=0.2
    )


def judged_car(oval, s: float = 3.0) -> tuple[CarOnTrack, carstep.Drive]:
    """A car driven one step at ``s`` metres, then judged as having crashed (one reset left)."""
    car = CarOnTrack(CarSim(), RaceTracker(RaceRules(resets=1), oval.length, closed=True))
    carstep.place(car, oval, s)
    car.tracker.start(car.s)
    step = carstep.drive(car, oval, 0.0, 1.0, lambda loc: RaceObject(0.0, 0.0, kind=KIND_BOX))
    assert step.judged.status is Status.CRASHED and step.judged.reset
    return car, step


def test_after_running_into_a_car_the_car_stays_where_it_is_at_rest(oval):
    car, step = judged_car(oval)
    hit = RaceObject(0.0, 0.0, kind=KIND_RACER)
    x, y, yaw = car.pose.x, car.pose.y, car.pose.yaw
    carstep.respawn(car, oval, carstep.Drive(**{**vars(step), "crash": hit}),
                    spot_near=lambda s: pytest.fail("no spot is asked for"))  # fmt: skip
    assert (car.pose.x, car.pose.y, car.pose.yaw, car.pose.speed) == (x, y, yaw, 0.0)
    assert car.sim.pose().speed == pytest.approx(0.0, abs=1e-6)
    car.sim.close()


def test_after_running_into_a_box_the_car_goes_to_the_spot_and_progress_with_it(oval):
    car, step = judged_car(oval)
    distance = car.tracker.distance
    carstep.respawn(car, oval, step, spot_near=lambda s: Spot(s - 1.0, 0.2))
    assert car.s == pytest.approx(step.loc.s - 1.0, abs=1e-6)
    assert oval.locate(*car.point).distance == pytest.approx(0.2, abs=1e-6)
    assert car.tracker.distance == pytest.approx(distance - 1.0, abs=1e-6)  # 1 m of lap lost
    assert car.pose.yaw == pytest.approx(oval.heading_at(car.s))
    car.sim.close()


def test_the_trace_action_is_the_index_or_the_rounded_pair():
    discrete = ActionSpec.parse(None)
    continuous = ActionSpec.parse(CONTINUOUS)
    assert carstep.trace_action(discrete, np.array([7]), (0.0, 1.0)) == 7
    assert carstep.trace_action(discrete, 3, (0.0, 1.0)) == 3
    pair = carstep.trace_action(continuous, None, (12.345678, math.pi))
    assert pair == (12.3457, 3.1416)


def straight_run(oval, multiplier: float, *, race: bool, steps: int = 24) -> tuple[float, float]:
    """Metres along the centre line that a car covers in ``steps`` steps straight ahead from
    the start line at 1 m/s commanded (the oval's straight), and its speed then (m/s), with
    ``multiplier`` set before the first step (a race's car, or a car stepped on its own
    through :func:`carstep.drive`, as RacingEnv steps it)."""
    if race:
        contest = HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS)], rules=RULES)
        contest.reset()
        car = contest.cars[0]
        car.speed_multiplier = multiplier
        start = car.s
        for _ in range(steps):
            contest.step([np.asarray([0.0, 1.0], dtype=np.float32)])
        assert car.speeds == [multiplier] * steps  # recorded, one per trace row
        contest.close()
        return car.s - start, car.pose.speed
    car = CarOnTrack(CarSim(), RaceTracker(RULES, oval.length, closed=True))
    carstep.place(car, oval, 0.0)
    car.tracker.start(car.s)
    car.speed_multiplier = multiplier
    start = car.s
    for _ in range(steps):
        step = carstep.drive(car, oval, 0.0, 1.0, lambda loc: None)
        assert step.speed == 1.0 and step.multiplier == multiplier  # the action, the multiplier
    car.sim.close()
    return car.s - start, car.pose.speed


@pytest.mark.parametrize("race", [True, False], ids=["race", "env-step"])
def test_the_speed_multiplier_scales_the_cars_speed_on_a_straight(oval, race):
    (slow, v_slow), (normal, v_normal), (fast, v_fast) = (
        straight_run(oval, m, race=race) for m in (0.5, 1.0, 1.5)
    )
    assert (v_slow, v_normal, v_fast) == pytest.approx((0.5, 1.0, 1.5), abs=0.03)
    # 1.6 s at 0.5, 1 and 1.5 m/s: the distances scale with the multiplier (less the start).
    assert 0.0 < slow < normal < fast
    assert slow / normal == pytest.approx(0.5, abs=0.07)
    assert fast / normal == pytest.approx(1.5, abs=0.1)


def test_the_driven_speed_is_clipped_to_the_cars_limits():
    assert carstep.driven_speed(2.0, 1.0) == 2.0
    assert carstep.driven_speed(2.0, 1.5) == pytest.approx(3.0)
    assert carstep.driven_speed(3.5, 1.5) == MAX_SPEED
    assert carstep.driven_speed(0.15, 0.5) == MIN_SPEED


def test_the_race_step_is_the_one_step():
    """No copy of the step is left in the race: it drives, respawns and traces through
    carstep (the module names no physics of its own)."""
    import inspect

    from racing import headtohead

    source = inspect.getsource(headtohead)
    for copied in ("sim.step(", "wheel_contacts", "tracker.update(", "closest_waypoints("):
        assert copied not in source
