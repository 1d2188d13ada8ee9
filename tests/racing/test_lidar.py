"""LIDAR: ranges against known geometry, DeepRacer's sector forms, and the Dict observation."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import racing
from racing.car import Pose
from racing.lidar import (
    BEAM_ANGLES_RAD,
    LIDAR_MOUNT_HEIGHT_M,
    LIDAR_MOUNT_X_M,
    LidarSensor,
    cast,
    sector_discretize,
)
from racing.objects import BOX_LENGTH_M, BOX_WIDTH_M, RaceObject
from racing.race import RaceConfig

CAR = Pose(0.0, 0.0, 0.0)
"""A car at the origin facing +x; its LIDAR sits at (0.03, 0) and faces -x."""


def test_a_box_behind_is_seen_at_its_distance():
    box = RaceObject(-1.0, 0.0)  # 0.24 m long along x: its near face is at x = -0.88
    ranges = cast(CAR, [box])
    face = LIDAR_MOUNT_X_M - (-1.0 + BOX_LENGTH_M / 2)
    # The two beams nearest straight back (±2.6° off it) hit the face square on.
    middle = np.argsort(np.abs(BEAM_ANGLES_RAD))[:2]
    assert ranges[middle] == pytest.approx(face / np.cos(BEAM_ANGLES_RAD[middle]), rel=1e-9)
    hits = np.isfinite(ranges)
    # The box is 0.39 m wide: beams within ±atan(0.195 / 0.91) of the back see it.
    half_angle = math.atan((BOX_WIDTH_M / 2) / face)
    assert np.array_equal(hits, np.abs(BEAM_ANGLES_RAD) < half_angle)


def test_a_box_to_the_left_and_a_rotated_car():
    box = RaceObject(LIDAR_MOUNT_X_M, 0.8)  # beside the sensor, 0.8 - 0.195 m to the left
    ranges = cast(CAR, [box])
    assert np.nanmin(ranges) == pytest.approx(0.8 - BOX_WIDTH_M / 2, rel=0.01)
    # Beam index grows counter-clockwise from 30° left of ahead: left side = the first third.
    assert int(np.argmin(ranges)) < 32
    # The same scene turned by 90° reads the same.
    turned = Pose(0.0, 0.0, math.pi / 2)
    rotated_box = RaceObject(-0.8, LIDAR_MOUNT_X_M, heading=math.pi / 2)
    assert cast(turned, [rotated_box]) == pytest.approx(ranges, rel=1e-9)


def test_straight_ahead_is_blind_and_the_track_has_no_walls():
    # The sensor faces backwards and covers ±150°: the 60° ahead are not scanned.
    assert np.all(np.isinf(cast(CAR, [RaceObject(1.0, 0.0)])))
    assert np.all(np.isinf(cast(CAR, [])))
    # Nearest object wins; an object lower than the sensor is not hit.
    near, far = RaceObject(-0.6, 0.0), RaceObject(-1.5, 0.0)
    face = LIDAR_MOUNT_X_M + 0.6 - BOX_LENGTH_M / 2
    nearest_beam = np.abs(BEAM_ANGLES_RAD).min()
    assert np.min(cast(CAR, [far, near])) == pytest.approx(face / math.cos(nearest_beam))
    assert np.all(np.isinf(cast(CAR, [RaceObject(-0.6, 0.0, height=0.1)])))


def test_observations_follow_deepracers_filters():
    box = RaceObject(-0.6, 0.0)  # near face 0.51 m behind the sensor
    rng = np.random.default_rng(0)
    lidar = LidarSensor("LIDAR").observe(CAR, [box], rng)
    assert lidar.dtype == np.float32 and lidar.shape == (64,)
    assert lidar.min() == pytest.approx(0.51, abs=0.04)  # noise σ = 0.01 m
    assert lidar.max() == 1.0 and lidar.min() >= 0.15  # no return reads as the 1 m clip
    assert LidarSensor("LIDAR").space.contains(lidar)
    ranges = np.full(64, np.inf)
    ranges[30] = 0.4  # sector 3 (beams 24-31)
    ranges[50] = 1.1  # sector 6
    assert list(sector_discretize(ranges, 8, 1, 0.5)) == [0, 0, 0, 1, 0, 0, 0, 0]
    grid = sector_discretize(ranges, 8, 8, 2.0).reshape(8, 8)
    assert grid[3].tolist() == [0, 1, 0, 0, 0, 0, 0, 0]  # 0.4 m: bin 1 of 0.25 m bins
    assert grid[6].tolist() == [0, 0, 0, 0, 1, 0, 0, 0]  # 1.1 m: bin 4
    assert grid[[0, 1, 2, 4, 5, 7]].sum() == 0  # nothing within 2 m: all zeros


SENSORS = [
    [camera, *lidar]
    for camera in ("FRONT_FACING_CAMERA", "STEREO_CAMERAS")
    for lidar in ([], ["LIDAR"], ["SECTOR_LIDAR"], ["DISCRETIZED_SECTOR_LIDAR"])
]


@pytest.mark.parametrize("sensors", SENSORS, ids=["+".join(s) for s in SENSORS])
def test_env_checker_passes_for_every_sensor_combination(reinvent, sensors):
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", number_of_objects=4, randomize_objects=True)
    env = gym.make(racing.ENV_ID, track=reinvent, sensors=sensors, race=race)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space")
        check_env(env.unwrapped, skip_render_check=True)
    space = env.observation_space
    if len(sensors) == 1:
        assert isinstance(space, gym.spaces.Box)
    else:
        assert isinstance(space, gym.spaces.Dict) and set(space.spaces) == set(sensors)
    env.close()


def test_the_env_lidar_sees_a_box_beside_the_start(reinvent):
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_positions=((0.3, 1),))
    env = racing.env.RacingEnv(reinvent, sensors=["FRONT_FACING_CAMERA", "LIDAR"], race=race)
    # Starting level with the box: the car is moved to the other lane, the box beside it.
    obs, info = env.reset(seed=0, options={"start_progress": 30.0})
    assert info["params"]["is_left_of_center"] is False
    assert obs["LIDAR"].min() < 0.5
    assert obs["FRONT_FACING_CAMERA"].shape == (120, 160, 1)
    env.close()


def test_cast_agrees_with_pybullets_rays_against_the_bodies(reinvent):
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", number_of_objects=6)
    env = racing.env.RacingEnv(reinvent, race=race)
    for progress in (8.0, 30.0, 55.0):  # a box beside or behind the car each time
        env.reset(seed=0, options={"start_progress": progress})
        pose = env.pose
        ox = pose.x + math.cos(pose.yaw) * LIDAR_MOUNT_X_M
        oy = pose.y + math.sin(pose.yaw) * LIDAR_MOUNT_X_M
        angles = BEAM_ANGLES_RAD + pose.yaw + math.pi
        starts = [[ox, oy, LIDAR_MOUNT_HEIGHT_M]] * 64
        ends = [
            [ox + 12 * math.cos(a), oy + 12 * math.sin(a), LIDAR_MOUNT_HEIGHT_M] for a in angles
        ]
        rays = env.sim.client.rayTestBatch(starts, ends)
        bullet = np.array([hit[2] * 12 if hit[0] >= 0 else np.inf for hit in rays])
        ours = cast(pose, env.objects)
        # A beam grazing a corner may fall either side of Bullet's collision margin.
        assert (np.isfinite(ours) != np.isfinite(bullet)).sum() <= 1
        finite = np.isfinite(ours) & np.isfinite(bullet)
        assert finite.sum() >= 3
        assert ours[finite] == pytest.approx(bullet[finite], abs=2e-3)  # Bullet's margin
    env.close()
