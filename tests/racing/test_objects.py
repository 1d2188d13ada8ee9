"""Boxes and bot cars: placement, bot driving, and every object key of ``params`` checked
against the PyBullet bodies on reinvent_base (a straight and a curved section)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import LinearRing, Point

from racing.env import RacingEnv
from racing.objects import BOX_WIDTH_M, KIND_BOT, Lanes, spread
from racing.params import closest_objects
from racing.race import RaceConfig


def fractions_on(track, *, curved: bool) -> float:
    """A track fraction (0.07-0.90) on the straightest or the most curved stretch."""
    candidates = np.linspace(0.1, 0.85, 76)
    segs = [track.segment_at(f * track.length) for f in candidates]
    k = track.curvature[segs]
    return float(candidates[int(np.argmax(k) if curved else np.argmin(k))])


def body_poses(env: RacingEnv) -> list[tuple[float, float, float]]:
    """``(x, y, yaw)`` of every object's PyBullet body: the simulator's own state."""
    poses = []
    for body in env.world.bodies.body_ids:
        (x, y, _), quat = env.sim.client.getBasePositionAndOrientation(body)
        yaw = env.sim.client.getEulerFromQuaternion(quat)[2]
        poses.append((x, y, yaw))
    return poses


def check_object_params(env: RacingEnv, params: dict) -> None:
    """Every object key against the bodies, with an independent (shapely) projection."""
    track = env.track
    centre = LinearRing(track.centre)
    poses = body_poses(env)
    flat = [v for point in params["objects_location"] for v in point]
    assert flat == pytest.approx([v for x, y, _ in poses for v in (x, y)], abs=1e-9)
    expected_s = [centre.project(Point(x, y)) for x, y, _ in poses]
    # shapely measures from the ring's first point, which is the track's start line.
    assert params["objects_distance"] == pytest.approx(expected_s, abs=1e-6)
    expected_d = [centre.distance(Point(x, y)) for x, y, _ in poses]
    assert params["objects_distance_from_center"] == pytest.approx(expected_d, abs=1e-6)
    for (x, y, _), left, s in zip(poses, params["objects_left_of_center"], expected_s, strict=True):
        # Left in the driving direction: the cross product of the heading and the offset.
        cx, cy = track.point_at(s)
        h = track.heading_at(s)
        assert left is (math.cos(h) * (y - cy) - math.sin(h) * (x - cx) > 0)
    car_s = centre.project(Point(params["x"], params["y"]))
    order = sorted(range(len(expected_s)), key=expected_s.__getitem__)
    nxt = next((i for i in order if expected_s[i] > car_s), order[0])
    assert params["closest_objects"][1] == nxt
    assert params["closest_objects"][0] == order[order.index(nxt) - 1]
    for obj, (_, _, yaw), heading, speed in zip(
        env.objects, poses, params["objects_heading"], params["objects_speed"], strict=True
    ):
        if obj.kind == KIND_BOT:
            assert heading == pytest.approx(math.degrees(yaw), abs=1e-6)
            assert speed == env.race.bot_speed
        else:
            assert heading == 0.0 and speed == 0.0  # DeepRacer's static obstacles


@pytest.mark.parametrize("curved", [False, True], ids=["straight", "curve"])
def test_box_params_match_the_bodies(reinvent, curved):
    f = fractions_on(reinvent, curved=curved)
    other = f + 0.2 if f < 0.6 else f - 0.2
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_positions=((f, 1), (other, -1)))
    env = RacingEnv(reinvent, race=race, start="start_line")
    _, info = env.reset(seed=0, options={"start_progress": 100 * f - 8})
    params = info["params"]
    check_object_params(env, params)
    # Fixed positions: track fraction along the centre line, lane 1 inner (left on this
    # counter-clockwise track) and -1 outer, at the lane midline.
    assert params["objects_distance"][0] == pytest.approx(f * reinvent.length, abs=0.02)
    assert params["objects_left_of_center"] == [True, False]
    half = reinvent.width_at(reinvent.locate(*params["objects_location"][0])) / 4
    assert params["objects_distance_from_center"][0] == pytest.approx(half, abs=0.02)
    assert params["closest_objects"][1] == 0  # the box at f is next
    assert params["object_in_camera"] is True  # 8 % of the lap ahead, in the car's lane
    for _ in range(10):
        *_, info = env.step(5)
    check_object_params(env, info["params"])
    env.close()


def test_moving_bot_params_match_the_bodies(reinvent):
    race = RaceConfig(
        race_type="HEAD_TO_BOT",
        number_of_bots=3,
        bot_speed=0.8,
        bot_lane_change=True,
        lane_change_min_s=1.0,
        lane_change_max_s=1.5,
    )
    env = RacingEnv(reinvent, race=race, start="start_line")
    _, info = env.reset(seed=3)
    before = info["params"]["objects_distance"]
    lefts = set()
    for _ in range(60):  # 4 s: every bot starts at least one lane change
        *_, info = env.step(0)  # hard left at 0.4 m/s: the car circles near the start
        params = info["params"]
        check_object_params(env, params)
        lefts.update(enumerate(params["objects_left_of_center"]))
    after = params["objects_distance"]
    moved = [(b - a) % reinvent.length for a, b in zip(before, after, strict=True)]
    # Bots keep their speed along the centre line (a lane is not the centre line: ±3 %).
    assert moved == pytest.approx([0.8 * 4.0] * 3, rel=0.06)
    assert len(lefts) == 6  # each bot was seen in both lanes
    env.close()


def test_bots_keep_their_distance(reinvent):
    race = RaceConfig(
        race_type="HEAD_TO_BOT", number_of_bots=6, randomize_bots=True, bot_lane_change=True
    )
    env = RacingEnv(reinvent, race=race)
    env.reset(seed=11)
    for _ in range(100):
        env.world.advance(0.2)
        s = sorted(loc.s for loc in env.world.locations)
        gaps = np.diff(s + [s[0] + reinvent.length])
        assert gaps.min() >= 2.0 - 0.05  # 2 m along the centre line, less a lane's bend
    env.close()


def test_random_placement_keeps_the_gap_and_follows_the_seed(reinvent):
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", number_of_objects=6, randomize_objects=True)
    env = RacingEnv(reinvent, race=race)
    seen = []
    for seed in (1, 2, 1):
        _, info = env.reset(seed=seed)
        dists = info["params"]["objects_distance"]
        assert np.diff(sorted(dists)).min() >= 2.0 - 0.05
        assert min(dists) >= 2.0 - 0.05 and max(dists) <= reinvent.length - 1.0 + 0.05
        seen.append((dists, info["params"]["objects_left_of_center"]))
    assert seen[0] == seen[2] and seen[0] != seen[1]
    # Placed by the simulator without randomizing: evenly spaced, lanes alternate inner first.
    fixed = RacingEnv(reinvent, race=RaceConfig(race_type="OBJECT_AVOIDANCE", number_of_objects=3))
    params = fixed.reset(seed=0)[1]["params"]
    even = np.linspace(2.0, reinvent.length - 1.0, 3)
    assert params["objects_distance"] == pytest.approx(even, abs=0.02)
    assert params["objects_left_of_center"] == [True, False, True]


def test_objects_that_cannot_fit_are_refused(reinvent):
    race = RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=6, min_bot_gap_m=3.0)
    with pytest.raises(ValueError, match="6 objects 3 m apart do not fit on a 17.7 m track"):
        RacingEnv(reinvent, race=race)
    assert spread(10.0, 1, 2.0, None) == [2.0]


def test_lanes_are_midlines_between_centre_and_borders(reinvent):
    lanes = Lanes(reinvent)
    for s in np.linspace(0, reinvent.length, 9)[:-1]:
        loc = reinvent.locate(*reinvent.point_at(s))
        width = reinvent.width_at(loc)
        assert lanes.offset(s, 1) == pytest.approx(width / 4, abs=0.03)  # inner = left (ccw)
        assert lanes.offset(s, -1) == pytest.approx(-width / 4, abs=0.03)
    cw = Lanes(reinvent.reversed())
    assert cw.offset(1.0, 1) < 0  # driven clockwise, the inner lane is on the right


def test_closest_objects_wrap_like_deepracer():
    assert closest_objects([5.0], 1.0) == (0, 0)
    assert closest_objects([2.0, 8.0, 15.0], 5.0) == (0, 1)
    assert closest_objects([15.0, 2.0, 8.0], 16.0) == (0, 1)  # next wraps past the start
    assert closest_objects([2.0, 8.0], 8.0) == (1, 0)  # level with an object: it is behind


def test_a_box_is_the_deepracer_package():
    assert pytest.approx(15.25 * 0.0254) == BOX_WIDTH_M


def test_vectorised_places_match_the_scalar_ones(reinvent):
    s = np.array([0.0, 3.3, 9.1, reinvent.length + 1.0])
    offsets = np.array([0.1, -0.2, 0.0, 0.15])
    seg, frac = reinvent.stations(s)
    xs, ys, headings = reinvent.points_at(seg, frac, offsets)
    for i in range(len(s)):
        assert (xs[i], ys[i]) == pytest.approx(reinvent.point_at(s[i], offsets[i]), abs=1e-12)
        assert headings[i] == pytest.approx(reinvent.heading_at(s[i] % reinvent.length))
    lanes = Lanes(reinvent)
    chosen = np.array([1, -1, -1, 1])
    vector = lanes.offsets(seg, frac, chosen)
    scalar = [lanes.offset(v, int(c)) for v, c in zip(s, chosen, strict=True)]
    assert vector == pytest.approx(scalar, abs=1e-12)
