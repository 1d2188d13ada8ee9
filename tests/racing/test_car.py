"""The PyBullet car: steering sign, Ackermann geometry, speed tracking, determinism."""

from __future__ import annotations

import math

import pytest

from racing.car import WHEELBASE_M, CarSim, ackermann_angles, wheel_speeds


@pytest.fixture
def sim():
    sim = CarSim()
    yield sim
    sim.close()


def drive(sim: CarSim, steering: float, speed: float, steps: int):
    sim.place(0.0, 0.0, 0.0)
    pose = None
    for _ in range(steps):
        pose = sim.step(steering, speed)
    return pose


def test_reaches_commanded_speed_in_a_straight_line(sim):
    pose = drive(sim, 0.0, 2.0, 45)
    assert pose.speed == pytest.approx(2.0, abs=0.05)
    assert abs(pose.y) < 0.01 and abs(pose.yaw) < 0.01
    assert pose.x == pytest.approx(2.0 * 3.0, rel=0.1)  # 3 s at about 2 m/s


def test_positive_steering_turns_left_at_the_kinematic_rate(sim):
    pose = drive(sim, 20.0, 1.0, 60)
    expected = 1.0 * math.tan(math.radians(20.0)) / WHEELBASE_M
    assert pose.yaw_rate == pytest.approx(expected, rel=0.05)
    right = drive(sim, -20.0, 1.0, 60)
    assert right.yaw_rate == pytest.approx(-expected, rel=0.05)


def test_grip_limits_cornering_at_high_speed(sim):
    pose = drive(sim, 30.0, 4.0, 60)
    kinematic = 4.0 * math.tan(math.radians(30.0)) / WHEELBASE_M
    assert abs(pose.yaw_rate) < 0.8 * kinematic  # the tyres slide: no magic grip


def test_ackermann_inner_wheel_turns_more():
    left, right = ackermann_angles(math.radians(20))
    assert left > math.radians(20) > right > 0
    left, right = ackermann_angles(math.radians(-20))
    assert right < math.radians(-20) < left < 0
    fl, fr, rl, rr = wheel_speeds(math.radians(20), 1.0)
    assert rl < rr and fl < fr  # outside wheels roll further


def test_same_calls_same_motion():
    a, b = CarSim(), CarSim()
    pa = drive(a, 12.0, 3.0, 50)
    pb = drive(b, 12.0, 3.0, 50)
    assert pa == pb
    a.close()
    b.close()


def test_car_reported_point_is_ahead_of_the_origin(sim):
    pose = drive(sim, 0.0, 1.0, 10)
    x, y = pose.point_ahead(0.14)
    assert x == pytest.approx(pose.x + 0.14, abs=1e-3) and y == pytest.approx(pose.y, abs=1e-3)
    xs, ys = pose.wheel_contacts()
    assert len(xs) == 4 and max(xs) - min(xs) == pytest.approx(WHEELBASE_M, abs=1e-3)
