"""The car and its world: a 1/18-scale Ackermann car on a flat floor, simulated by PyBullet.

Each :class:`CarSim` owns its own PyBullet client in DIRECT mode (no GUI, no shared state), so
any number of environments can live in one process. The car is a chassis with four wheels; the
two front wheels hang on steering knuckles turned to Ackermann angles, and all four wheels are
velocity-driven (DeepRacer's simulated car sets every wheel to speed / wheel radius). Control
runs at 15 Hz with a fixed number of physics sub-steps per control step, so a run is
deterministic for the same sequence of calls.

Frame: the car's origin is the middle of the rear axle on the ground; x forward, y left.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass

from racing.quiet_pybullet import bullet_client, pb

CONTROL_HZ = 15.0
"""Agent decisions per simulated second (DeepRacer's camera rate)."""
SUBSTEPS = 4
"""Physics sub-steps per control step (60 Hz physics)."""
GRAVITY = 9.81

WHEELBASE_M = 0.165
"""Distance between the front and rear axles, metres."""
TRACK_WIDTH_M = 0.155
"""Distance between the left and right wheel centres, metres."""
WHEEL_RADIUS_M = 0.035
"""DeepRacer's wheel radius for physics versions 3 and later."""
CHASSIS_HALF_EXTENTS = (0.14, 0.06, 0.02)
"""Half length, half width and half height of the chassis box, metres."""
CHASSIS_CENTRE_X = 0.08
"""Chassis centre ahead of the rear axle, metres."""
CHASSIS_CENTRE_Z = 0.06
"""Height of the chassis centre above the ground at rest, metres."""
CHASSIS_MASS_KG = 1.2
WHEEL_MASS_KG = 0.05
REPORTED_POINT_AHEAD_M = 0.14
"""DeepRacer reports x, y at a point 0.14 m ahead of the car's origin."""

MAX_STEERING_DEG = 30.0
MIN_SPEED = 0.1
MAX_SPEED = 4.0
WHEEL_TORQUE_NM = 0.35
"""Per-wheel drive torque limit: about 8 m/s² of acceleration on a 1.4 kg car."""
STEERING_RATE_RAD_S = 6.0
"""Top speed of the steering servo (about 0.17 s for 60°)."""
FRICTION = 1.0

# Link indices of the multibody (the base is -1).
FL_KNUCKLE, FL_WHEEL, FR_KNUCKLE, FR_WHEEL, RL_WHEEL, RR_WHEEL = range(6)
_WHEELS = [FL_WHEEL, FR_WHEEL, RL_WHEEL, RR_WHEEL]
_KNUCKLES = [FL_KNUCKLE, FR_KNUCKLE]


@dataclass(frozen=True, slots=True)
class Pose:
    """Where the car is: origin (rear-axle middle) ``x, y`` in metres, ``yaw`` in radians
    (counter-clockwise from +x), forward speed ``speed`` in m/s and yaw rate in rad/s."""

    x: float
    y: float
    yaw: float
    speed: float = 0.0
    yaw_rate: float = 0.0

    def point_ahead(self, distance: float) -> tuple[float, float]:
        return self.x + distance * math.cos(self.yaw), self.y + distance * math.sin(self.yaw)

    def wheel_contacts(self) -> tuple[list[float], list[float]]:
        """Ground contact points of the four wheels (FL, FR, RL, RR): lists of x and of y."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        half = TRACK_WIDTH_M / 2
        xs, ys = [], []
        for fx, fy in ((WHEELBASE_M, half), (WHEELBASE_M, -half), (0.0, half), (0.0, -half)):
            xs.append(self.x + c * fx - s * fy)
            ys.append(self.y + s * fx + c * fy)
        return xs, ys


def ackermann_angles(steering_rad: float) -> tuple[float, float]:
    """Left and right front-wheel angles for a bicycle-model steering angle (positive = left)."""
    if abs(steering_rad) < 1e-6:
        return 0.0, 0.0
    radius = WHEELBASE_M / math.tan(abs(steering_rad))
    inner = math.atan(WHEELBASE_M / (radius - TRACK_WIDTH_M / 2))
    outer = math.atan(WHEELBASE_M / (radius + TRACK_WIDTH_M / 2))
    return (inner, outer) if steering_rad > 0 else (-outer, -inner)


def wheel_speeds(steering_rad: float, speed: float) -> list[float]:
    """Wheel angular velocities (FL, FR, RL, RR), rad/s, for ``speed`` at the rear-axle middle.

    Each wheel turns at the rate its own arc needs (an ideal differential), so the tyres do not
    scrub in corners and the car follows the steering it is given.
    """
    w = speed / WHEEL_RADIUS_M
    if abs(steering_rad) < 1e-6:
        return [w, w, w, w]
    radius = WHEELBASE_M / math.tan(abs(steering_rad))
    half = TRACK_WIDTH_M / 2
    inner_rear = (radius - half) / radius
    outer_rear = (radius + half) / radius
    inner_front = math.hypot(WHEELBASE_M, radius - half) / radius
    outer_front = math.hypot(WHEELBASE_M, radius + half) / radius
    if steering_rad > 0:  # turning left: the left wheels are on the inside
        return [w * inner_front, w * outer_front, w * inner_rear, w * outer_rear]
    return [w * outer_front, w * inner_front, w * outer_rear, w * inner_rear]


@contextlib.contextmanager
def _quiet_stdout():
    """Silence the process's C-level stdout for a moment (file descriptor 1)."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


class _RawClient:
    """The few PyBullet calls made every step, bound to one physics client id."""

    def __init__(self, client_id: int) -> None:
        from functools import partial

        for name in (
            "setJointMotorControlArray",
            "stepSimulation",
            "getBasePositionAndOrientation",
            "getBaseVelocity",
        ):
            setattr(self, name, partial(getattr(pb, name), physicsClientId=client_id))


class CarSim:
    """One PyBullet world with one car. Call :meth:`place`, then :meth:`step` once per action."""

    def __init__(self, *, substeps: int = SUBSTEPS) -> None:
        if substeps < 1:
            raise ValueError("substeps must be at least 1")
        self.dt = 1.0 / CONTROL_HZ
        with _quiet_stdout():  # PyBullet's C code prints "argv[0]=" on every connect
            self.client = bullet_client.BulletClient(connection_mode=pb.DIRECT)
        c = self.client
        c.setGravity(0, 0, -GRAVITY)
        c.setPhysicsEngineParameter(
            fixedTimeStep=self.dt, numSubSteps=substeps, deterministicOverlappingPairs=1
        )
        plane = c.createCollisionShape(pb.GEOM_PLANE)
        self.ground = c.createMultiBody(0, plane)
        c.changeDynamics(self.ground, -1, lateralFriction=FRICTION)
        self.car = self._build_car()
        # Bound methods of the raw client skip BulletClient's per-call attribute lookup.
        self._pb = _RawClient(c._client)
        self._steer = 0.0

    def _build_car(self) -> int:
        c = self.client
        hx, hy, hz = CHASSIS_HALF_EXTENTS
        chassis = c.createCollisionShape(pb.GEOM_BOX, halfExtents=[hx, hy, hz])
        wheel = c.createCollisionShape(pb.GEOM_SPHERE, radius=WHEEL_RADIUS_M)
        half = TRACK_WIDTH_M / 2
        # The base frame sits at the chassis centre; the wheel axles are below it.
        axle_z = WHEEL_RADIUS_M - CHASSIS_CENTRE_Z
        front_x = WHEELBASE_M - CHASSIS_CENTRE_X
        rear_x = -CHASSIS_CENTRE_X
        spec = [  # (mass, collision, position, parent, joint axis)
            (0.02, -1, [front_x, half, axle_z], 0, [0, 0, 1]),
            (WHEEL_MASS_KG, wheel, [0, 0, 0], FL_KNUCKLE + 1, [0, 1, 0]),
            (0.02, -1, [front_x, -half, axle_z], 0, [0, 0, 1]),
            (WHEEL_MASS_KG, wheel, [0, 0, 0], FR_KNUCKLE + 1, [0, 1, 0]),
            (WHEEL_MASS_KG, wheel, [rear_x, half, axle_z], 0, [0, 1, 0]),
            (WHEEL_MASS_KG, wheel, [rear_x, -half, axle_z], 0, [0, 1, 0]),
        ]
        n = len(spec)
        car = c.createMultiBody(
            CHASSIS_MASS_KG,
            chassis,
            -1,
            [0, 0, 0.1],
            [0, 0, 0, 1],
            linkMasses=[s[0] for s in spec],
            linkCollisionShapeIndices=[s[1] for s in spec],
            linkVisualShapeIndices=[-1] * n,
            linkPositions=[s[2] for s in spec],
            linkOrientations=[[0, 0, 0, 1]] * n,
            linkInertialFramePositions=[[0, 0, 0]] * n,
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
            linkParentIndices=[s[3] for s in spec],
            linkJointTypes=[pb.JOINT_REVOLUTE] * n,
            linkJointAxis=[s[4] for s in spec],
        )
        for j in range(n):
            c.setJointMotorControl2(car, j, pb.VELOCITY_CONTROL, force=0)
            c.changeDynamics(
                car, j, lateralFriction=FRICTION, rollingFriction=0.0, spinningFriction=0.0
            )
        c.changeDynamics(car, -1, linearDamping=0.0, angularDamping=0.0)
        return car

    def place(self, x: float, y: float, yaw: float, speed: float = 0.0) -> None:
        """Put the car's origin at ``(x, y)`` facing ``yaw`` radians, rolling at ``speed`` m/s."""
        c = self.client
        cx = x + CHASSIS_CENTRE_X * math.cos(yaw)
        cy = y + CHASSIS_CENTRE_X * math.sin(yaw)
        c.resetBasePositionAndOrientation(
            self.car, [cx, cy, CHASSIS_CENTRE_Z], c.getQuaternionFromEuler([0, 0, yaw])
        )
        vx, vy = speed * math.cos(yaw), speed * math.sin(yaw)
        c.resetBaseVelocity(self.car, [vx, vy, 0], [0, 0, 0])
        for j in _KNUCKLES:
            c.resetJointState(self.car, j, 0.0, 0.0)
        for j in _WHEELS:
            c.resetJointState(self.car, j, 0.0, speed / WHEEL_RADIUS_M)
        self._steer = 0.0

    def step(self, steering_deg: float, speed: float) -> Pose:
        """Drive one control step (1/15 s) with the commanded steering angle and speed."""
        c = self._pb
        steer = math.radians(steering_deg)
        # The servo slews at a finite rate, so steering is not instantaneous.
        max_delta = STEERING_RATE_RAD_S * self.dt
        self._steer += max(-max_delta, min(max_delta, steer - self._steer))
        left, right = ackermann_angles(self._steer)
        c.setJointMotorControlArray(
            self.car,
            _KNUCKLES,
            pb.POSITION_CONTROL,
            targetPositions=[left, right],
            forces=[5.0, 5.0],
        )
        c.setJointMotorControlArray(
            self.car,
            _WHEELS,
            pb.VELOCITY_CONTROL,
            targetVelocities=wheel_speeds(self._steer, speed),
            forces=[WHEEL_TORQUE_NM] * 4,
        )
        c.stepSimulation()
        return self.pose()

    def snapshot(self) -> tuple[int, float]:
        """The world's state now (the car's bodies and joints, the steering servo's angle), for
        :meth:`restore`; :meth:`forget` frees it. A search that tries actions ahead uses it."""
        return self.client.saveState(), self._steer

    def restore(self, state: tuple[int, float]) -> None:
        """Put the world back as it was at :meth:`snapshot`; the next steps then go as they
        went from there (the same commands give the same poses)."""
        self.client.restoreState(state[0])
        self._steer = state[1]

    def forget(self, state: tuple[int, float]) -> None:
        self.client.removeState(state[0])

    def pose(self) -> Pose:
        c = self._pb
        (cx, cy, _), orn = c.getBasePositionAndOrientation(self.car)
        (vx, vy, _), (_, _, wz) = c.getBaseVelocity(self.car)
        # yaw from the quaternion (x, y, z, w), ignoring roll and pitch
        qx, qy, qz, qw = orn
        yaw = math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
        cos_y, sin_y = math.cos(yaw), math.sin(yaw)
        return Pose(
            x=cx - CHASSIS_CENTRE_X * cos_y,
            y=cy - CHASSIS_CENTRE_X * sin_y,
            yaw=yaw,
            speed=vx * cos_y + vy * sin_y,
            yaw_rate=wz,
        )

    def close(self) -> None:
        if self.client is not None:
            try:
                self.client.disconnect()
            except pb.error:
                pass
            self.client = None  # type: ignore[assignment]

    def __del__(self) -> None:  # pragma: no cover - best effort on garbage collection
        try:
            self.close()
        except Exception:
            pass
