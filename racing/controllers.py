"""Scripted drivers: pure pursuit along a lane of the track, and one that dodges boxes.

Used to prove tracks and physics (a scripted car must lap every track), to drive bot cars, and
as a baseline. They act through the env's normal action interface.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from racing.car import WHEELBASE_M, Pose
from racing.objects import Lanes, RaceObject
from racing.track import Track

GRIP_MS2 = 4.0
"""Lateral acceleration the controller plans for, m/s² (the tyres hold about 9)."""


class PurePursuitDriver:
    """Steers towards a point ``lookahead`` metres ahead on the line ``offset`` metres left of
    the centre line, at a speed that keeps lateral acceleration under :data:`GRIP_MS2`."""

    def __init__(
        self,
        track: Track,
        *,
        lookahead: float = 0.45,
        max_speed: float = 3.0,
        min_speed: float = 0.5,
        offset: float = 0.0,
    ) -> None:
        self.track = track
        self.lookahead = lookahead
        self.max_speed = max_speed
        self.min_speed = min_speed
        self.offset = offset

    def act(self, pose: Pose) -> tuple[float, float]:
        """``(steering_deg, speed)`` for a car at ``pose`` (origin = rear-axle middle)."""
        loc = self.track.locate(pose.x, pose.y)
        look = self.lookahead + 0.12 * max(pose.speed, 0.0)
        tx, ty = self.track.point_at(loc.s + look, self.offset)
        dx, dy = tx - pose.x, ty - pose.y
        alpha = math.atan2(dy, dx) - pose.yaw
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
        dist = max(math.hypot(dx, dy), 1e-6)
        steer = math.atan2(2.0 * WHEELBASE_M * math.sin(alpha), dist)
        steer_deg = max(-30.0, min(30.0, math.degrees(steer)))
        curvature = self.track.curvature_ahead(loc.s, 0.5 + 0.5 * max(pose.speed, 0.0))
        speed = math.sqrt(GRIP_MS2 / curvature) if curvature > 1e-6 else self.max_speed
        speed = max(self.min_speed, min(self.max_speed, speed))
        return steer_deg, speed


AVOID_AHEAD_M = 2.5
"""How far ahead along the track :class:`AvoidingDriver` looks for boxes, metres."""
AVOID_BEHIND_M = 0.4
"""A box counts until it is this far behind the car's origin along the track, metres."""
DODGE_WIDENING = 1.25
"""The dodging line runs this many times farther out than the free lane's midline: a box
fills most of its own lane, so the midline of the other lane leaves only centimetres."""


class AvoidingDriver(PurePursuitDriver):
    """Pure pursuit that dodges boxes: it drives the lane away from the nearest box ahead
    (within :data:`AVOID_AHEAD_M`) and keeps that lane until the next box calls for a change.
    A scripted baseline for object avoidance; it ignores bot cars' motion."""

    def __init__(self, track: Track, **kwargs: float) -> None:
        super().__init__(track, **kwargs)
        self.lanes = Lanes(track)

    def act_among(self, pose: Pose, objects: Sequence[RaceObject]) -> tuple[float, float]:
        """``(steering_deg, speed)`` for a car at ``pose`` with ``objects`` on the track."""
        car_s = self.track.locate(pose.x, pose.y).s
        nearest: tuple[float, float, RaceObject] | None = None
        for obj in objects:
            loc = self.track.locate(obj.x, obj.y)
            gap = loc.s - car_s
            if self.track.closed:
                gap = (gap + self.track.length / 2) % self.track.length - self.track.length / 2
            if -AVOID_BEHIND_M < gap < AVOID_AHEAD_M and (nearest is None or gap < nearest[0]):
                nearest = (gap, loc.s, obj)
        if nearest is not None:
            gap, box_s, obj = nearest
            loc = self.track.locate(obj.x, obj.y)
            box_lane = self.lanes.lane_of(loc.distance if loc.left else -loc.distance)
            self.offset = DODGE_WIDENING * self.lanes.offset(box_s, -box_lane)
        return self.act(pose)
