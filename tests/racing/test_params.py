"""DeepRacer's params, checked numerically on reinvent_base at known poses."""

from __future__ import annotations

import math

import pytest

from racing.env import RacingEnv
from racing.params import PARAM_KEYS, SCENARIOS, heading_deg, scenario_params


@pytest.fixture
def env(reinvent):
    env = RacingEnv(reinvent, start="start_line")
    yield env
    env.close()


def params_at(env: RacingEnv, progress: float, offset: float = 0.0, turn: float = 0.0) -> dict:
    _, info = env.reset(
        seed=0,
        options={"start_progress": progress, "offset": offset, "heading_offset_deg": turn},
    )
    return info["params"]


def test_every_deepracer_key_is_present_with_its_type(env):
    params = params_at(env, 0.0)
    assert set(params) == set(PARAM_KEYS)
    assert len(PARAM_KEYS) == 27  # 23 documented + 4 undocumented
    for key in (
        "x",
        "y",
        "heading",
        "speed",
        "steering_angle",
        "progress",
        "track_width",
        "track_length",
        "distance_from_center",
        "projection_distance",
        "sim_time",
    ):
        assert isinstance(params[key], float), key
    for key in (
        "all_wheels_on_track",
        "is_left_of_center",
        "is_offtrack",
        "is_crashed",
        "is_reversed",
        "object_in_camera",
    ):
        assert isinstance(params[key], bool), key
    assert isinstance(params["steps"], int)
    # Time trial: object keys present and empty.
    for key in (
        "objects_location",
        "objects_distance",
        "objects_left_of_center",
        "objects_speed",
        "objects_heading",
        "objects_distance_from_center",
    ):
        assert params[key] == [], key
    assert params["closest_objects"] == [0, 0]


def test_on_the_centre_line_at_a_waypoint(env, reinvent):
    k = 30
    s = reinvent.cumulative[k] + 0.01
    params = params_at(env, 100 * s / reinvent.length)
    wx, wy = reinvent.waypoints[k]
    assert params["x"] == pytest.approx(wx, abs=0.02)
    assert params["y"] == pytest.approx(wy, abs=0.02)
    assert params["distance_from_center"] == pytest.approx(0.0, abs=1e-6)
    assert params["closest_waypoints"] == [k, k + 1]
    assert params["all_wheels_on_track"] and not params["is_offtrack"]
    assert params["track_width"] == pytest.approx(0.762, abs=0.01)
    assert params["track_length"] == pytest.approx(17.71, abs=0.01)
    assert params["projection_distance"] == pytest.approx(s, abs=1e-6)
    # Progress counts from the episode's start point, which is here.
    assert params["progress"] == 0.0
    seg = reinvent.waypoints[k + 1][0] - wx, reinvent.waypoints[k + 1][1] - wy
    assert params["heading"] == pytest.approx(math.degrees(math.atan2(seg[1], seg[0])), abs=0.5)
    assert params["waypoints"][0] == params["waypoints"][-1]  # closed loop


@pytest.mark.parametrize("side", [1, -1])
def test_at_each_border(env, reinvent, side):
    half = 0.762 / 2
    params = params_at(env, 25.0, offset=side * half)
    assert params["distance_from_center"] == pytest.approx(half, abs=0.01)
    assert params["is_left_of_center"] is (side > 0)
    # Half the car hangs over the border: not all wheels on, but not off track either.
    assert params["all_wheels_on_track"] is False
    assert params["is_offtrack"] is False


def test_left_of_centre_is_relative_to_the_driving_direction(reinvent):
    env = RacingEnv(reinvent, direction="cw", start="start_line")
    params = params_at(env, 25.0, offset=0.2)
    assert params["is_left_of_center"] is True
    assert params["is_reversed"] is True  # against the file's native order
    env.close()
    native = RacingEnv(reinvent, start="start_line")
    assert params_at(native, 25.0)["is_reversed"] is False
    native.close()


def test_facing_backwards(env, reinvent):
    ahead = params_at(env, 40.0)["heading"]
    backwards = params_at(env, 40.0, turn=180.0)["heading"]
    assert -180.0 <= backwards <= 180.0
    diff = (backwards - ahead + 180.0) % 360.0 - 180.0
    assert abs(abs(diff) - 180.0) < 1.0


def test_reversing_drops_progress_and_ends_the_episode(env):
    env.reset(seed=0, options={"start_progress": 50.0, "heading_offset_deg": 180.0})
    statuses = []
    for _ in range(40):
        _, _, terminated, _, info = env.step(5)  # straight, 1 m/s: backwards along the track
        statuses.append(info["status"])
        if terminated:
            break
    assert statuses[-1] in ("reversed", "off_track")
    assert info["progress"] == 0.0 or info["status"] == "reversed"


def test_steps_speed_and_steering_are_as_commanded(env):
    params_at(env, 0.0)
    _, _, _, _, info = env.step(7)  # action 7 of the default space: 15° left at 1.0 m/s
    p = info["params"]
    assert p["steps"] == 1
    assert p["steering_angle"] == 15.0
    assert p["speed"] == 1.0
    assert p["sim_time"] == pytest.approx(1 / 15)


def test_heading_range():
    assert heading_deg(math.pi) == 180.0
    assert heading_deg(-math.pi) == 180.0
    assert heading_deg(3 * math.pi / 2) == pytest.approx(-90.0)


@pytest.mark.parametrize("situation", SCENARIOS)
def test_scenarios_are_complete_and_consistent(reinvent, situation):
    params = scenario_params(reinvent, situation)
    assert set(params) == set(PARAM_KEYS)
    assert 0.0 <= params["progress"] <= 100.0
    if situation == "off_track":
        assert params["is_offtrack"] and not params["all_wheels_on_track"]
        assert params["distance_from_center"] > params["track_width"] / 2
    if situation == "reversed":
        assert params["is_reversed"] is True
    if situation == "with_objects":
        assert len(params["objects_location"]) == 3
        behind, ahead = params["closest_objects"]
        assert params["objects_distance"][ahead] >= params["projection_distance"]
        assert all(isinstance(v, float) for v in params["objects_heading"])
    if situation == "start_line":
        assert params["steps"] == 1 and params["speed"] == 0.1 and params["progress"] == 0.0


def test_scenario_rejects_unknown_situation(reinvent):
    with pytest.raises(ValueError, match="unknown situation"):
        scenario_params(reinvent, "moon")


def test_closest_objects_are_behind_and_ahead_along_the_track():
    from racing.car import Pose
    from racing.params import RaceObject, build_params
    from racing.tracks import TrackCatalog

    track = TrackCatalog().load("racecraft_oval")
    objects = [RaceObject(*track.point_at(s)) for s in (2.0, 8.0, 15.0)]
    car = track.locate(*track.point_at(5.0))
    params = build_params(track=track, pose=Pose(0, 0, 0), loc=car, wheels_on_track=4,
                          steering_angle=0.0, speed=1.0, progress=0.0, steps=1,
                          objects=objects)  # fmt: skip
    assert params["closest_objects"] == [0, 1]
    assert params["objects_distance"] == pytest.approx([2.0, 8.0, 15.0], abs=1e-6)
    near_end = track.locate(*track.point_at(track.length - 0.5))
    wrapped = build_params(track=track, pose=Pose(0, 0, 0), loc=near_end, wheels_on_track=4,
                           steering_angle=0.0, speed=1.0, progress=0.0, steps=1,
                           objects=objects)  # fmt: skip
    assert wrapped["closest_objects"] == [2, 0]  # ahead wraps past the start line
