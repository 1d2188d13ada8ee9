"""The fast homography camera against PyBullet's own renderer of the same scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racing.car import CarSim, Pose
from racing.sensors import (
    PinholeCamera,
    ReferenceCamera,
    SensorError,
    ground_for,
    validate_sensors,
)

POSES = [  # (progress along the track, offset left, heading turned by degrees)
    (0.0, 0.0, 0.0),
    (23.0, 0.15, 10.0),
    (47.0, -0.2, -25.0),
    (71.0, 0.0, 40.0),
    (90.0, 0.1, 180.0),
]


@pytest.fixture(scope="module")
def cameras(reinvent):
    sim = CarSim()
    fast = PinholeCamera(ground_for(reinvent, resolution=0.005, rgb=False))
    reference = ReferenceCamera(sim.client, ground_for(reinvent, resolution=0.005, rgb=True))
    yield fast, reference
    sim.close()


def pose_on(track, progress, offset, turn) -> Pose:
    s = progress / 100 * track.length
    x, y = track.point_at(s, offset)
    return Pose(x, y, track.heading_at(s) + math.radians(turn))


@pytest.mark.parametrize("progress, offset, turn", POSES)
def test_fast_camera_matches_pybullet_render(reinvent, cameras, progress, offset, turn):
    fast, reference = cameras
    pose = pose_on(reinvent, progress, offset, turn)
    a = fast.render(pose).astype(np.int16)
    b = reference.render(pose).astype(np.int16)
    # Above: the walls (the backdrop, and beyond the ground picture's margin) differ by design:
    # PyBullet shows its light background there. A few rows cover metres of far ground.
    ground = slice(fast.first_ground_row + 8, None)
    diff = np.abs(a[ground] - b[ground])
    assert diff.mean() < 12, f"mean abs difference {diff.mean():.1f}"
    # Same road where it matters: dark asphalt pixels agree (IoU).
    road_a, road_b = a[ground] < 70, b[ground] < 70
    union = np.logical_or(road_a, road_b).sum()
    if union:
        iou = np.logical_and(road_a, road_b).sum() / union
        assert iou > 0.9, f"road IoU {iou:.2f}"


def test_camera_looks_the_way_the_car_faces(reinvent, cameras):
    fast, _ = cameras
    ahead = fast.render(pose_on(reinvent, 5.0, 0.0, 0.0))
    # Along a straight, the dark road is centred: left and right halves balance.
    ground = ahead[fast.first_ground_row + 20 :]
    left = (ground[:, :80] < 70).sum()
    right = (ground[:, 80:] < 70).sum()
    assert abs(left - right) < 0.25 * (left + right)
    # Turned 60° to the left, the road lies to the right of the picture.
    turned = fast.render(pose_on(reinvent, 5.0, 0.0, 60.0))[fast.first_ground_row + 20 :]
    assert (turned[:, 80:] < 70).sum() > 1.3 * (turned[:, :80] < 70).sum()


def test_sensor_combinations():
    assert validate_sensors(["front_facing_camera"]) == ("FRONT_FACING_CAMERA",)
    with pytest.raises(SensorError, match="exactly one camera"):
        validate_sensors(["FRONT_FACING_CAMERA", "STEREO_CAMERAS"])
    with pytest.raises(SensorError, match="exactly one camera"):
        validate_sensors([])
    with pytest.raises(SensorError, match="unknown sensor"):
        validate_sensors(["RADAR"])
    # DeepRacer's combinations: a camera, optionally with one LIDAR (camera first).
    assert validate_sensors(["LIDAR", "STEREO_CAMERAS"]) == ("STEREO_CAMERAS", "LIDAR")
    for lidar in ("LIDAR", "SECTOR_LIDAR", "DISCRETIZED_SECTOR_LIDAR"):
        assert validate_sensors(["FRONT_FACING_CAMERA", lidar]) == ("FRONT_FACING_CAMERA", lidar)
    with pytest.raises(SensorError, match="exactly one camera"):
        validate_sensors(["LIDAR"])
    with pytest.raises(SensorError, match="at most one LIDAR"):
        validate_sensors(["FRONT_FACING_CAMERA", "LIDAR", "SECTOR_LIDAR"])
