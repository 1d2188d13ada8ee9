"""Scripted drivers: pure pursuit along a lane of the track.

Used to prove tracks and physics (a scripted car must lap every track), to drive bot cars, and
as a baseline. They act through the env's normal action interface.
"""

from __future__ import annotations

import math

from racing.car import WHEELBASE_M, Pose
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
