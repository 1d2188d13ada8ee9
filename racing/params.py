"""DeepRacer's reward-function input: the ``params`` dict, built from the simulator's state.

Every key of DeepRacer's ``params`` is present with DeepRacer's meaning and units, including the
four undocumented ones (``projection_distance``, ``objects_distance_from_center``,
``object_in_camera``, ``sim_time``). Object keys are present and empty in a time trial.

Units and conventions: ``x``, ``y`` metres at the point 0.14 m ahead of the car's origin;
``heading`` degrees in -180..180, counter-clockwise from +x; ``speed`` and ``steering_angle``
as commanded (m/s, degrees, positive = left); ``progress`` percent 0..100 from the episode's
start point; ``closest_waypoints`` ``[behind, ahead]``; ``is_left_of_center`` relative to the
driving direction; ``objects_heading`` in degrees (DeepRacer's documented unit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from racing.car import REPORTED_POINT_AHEAD_M, Pose
from racing.track import Location, Track

PARAM_KEYS = (
    "all_wheels_on_track",
    "x",
    "y",
    "heading",
    "speed",
    "steering_angle",
    "progress",
    "steps",
    "distance_from_center",
    "is_left_of_center",
    "is_offtrack",
    "is_crashed",
    "is_reversed",
    "track_width",
    "track_length",
    "waypoints",
    "closest_waypoints",
    "closest_objects",
    "objects_location",
    "objects_distance",
    "objects_left_of_center",
    "objects_speed",
    "objects_heading",
    "projection_distance",
    "objects_distance_from_center",
    "object_in_camera",
    "sim_time",
)


@dataclass(frozen=True, slots=True)
class RaceObject:
    """An obstacle box or a bot car: centre ``x, y`` (m), ``heading`` (rad), ``speed`` (m/s)."""

    x: float
    y: float
    heading: float = 0.0
    speed: float = 0.0
    length: float = 0.24
    width: float = 0.39
    height: float = 0.27
    kind: str = "box"


def heading_deg(yaw: float) -> float:
    """Yaw in radians to DeepRacer's heading in degrees, -180..180."""
    deg = math.degrees(yaw)
    deg = (deg + 180.0) % 360.0 - 180.0
    return 180.0 if deg == -180.0 else deg


def build_params(
    *,
    track: Track,
    pose: Pose,
    loc: Location,
    wheels_on_track: int,
    steering_angle: float,
    speed: float,
    progress: float,
    steps: int,
    is_crashed: bool = False,
    sim_time: float = 0.0,
    objects: tuple[RaceObject, ...] | list[RaceObject] = (),
    object_in_camera: bool = False,
) -> dict:
    """The ``params`` dict for one step. ``loc`` locates the reported point (0.14 m ahead)."""
    behind, ahead = track.closest_waypoints(loc)
    params = {
        "all_wheels_on_track": wheels_on_track == 4,
        "x": loc.x,
        "y": loc.y,
        "heading": heading_deg(pose.yaw),
        "speed": float(speed),
        "steering_angle": float(steering_angle),
        "progress": float(progress),
        "steps": int(steps),
        "distance_from_center": loc.distance,
        "is_left_of_center": loc.left,
        "is_offtrack": wheels_on_track == 0,
        "is_crashed": bool(is_crashed),
        "is_reversed": track.is_reversed,
        "track_width": track.width_at(loc),
        "track_length": track.length,
        "waypoints": track.waypoints,
        "closest_waypoints": [behind, ahead],
        "closest_objects": [0, 0],
        "objects_location": [],
        "objects_distance": [],
        "objects_left_of_center": [],
        "objects_speed": [],
        "objects_heading": [],
        "projection_distance": loc.s,
        "objects_distance_from_center": [],
        "object_in_camera": bool(object_in_camera),
        "sim_time": float(sim_time),
    }
    if objects:
        _add_objects(params, track, loc, objects)
    return params


def _add_objects(params: dict, track: Track, car: Location, objects) -> None:
    locs = [track.locate(o.x, o.y) for o in objects]
    params["objects_location"] = [(o.x, o.y) for o in objects]
    params["objects_distance"] = [lo.s for lo in locs]
    params["objects_left_of_center"] = [lo.left for lo in locs]
    params["objects_speed"] = [float(o.speed) for o in objects]
    params["objects_heading"] = [heading_deg(o.heading) for o in objects]
    params["objects_distance_from_center"] = [lo.distance for lo in locs]
    # Ahead = the nearest object in front of the car along the track, behind = the nearest one
    # behind it; on a loop every object is both, at some distance, so both always exist.
    if track.closed:
        gaps = [(lo.s - car.s) % track.length for lo in locs]
        ahead = min(range(len(gaps)), key=gaps.__getitem__)
        behind = max(range(len(gaps)), key=gaps.__getitem__)
    else:
        gaps = [lo.s - car.s for lo in locs]
        front = [i for i, g in enumerate(gaps) if g >= 0]
        back = [i for i, g in enumerate(gaps) if g < 0]
        ahead = min(front, key=gaps.__getitem__) if front else 0
        behind = max(back, key=gaps.__getitem__) if back else 0
    params["closest_objects"] = [behind, ahead]


# --------------------------------------------------------------------------- scenarios
SCENARIOS = ("start_line", "mid_lap", "near_finish", "off_track", "reversed", "with_objects")


def scenario_params(track: Track, situation: str) -> dict:
    """Realistic ``params`` for a named situation on a real track, for validating rewards.

    Situations: ``start_line`` (step 1 at the start, 0.1 m/s), ``mid_lap`` (half way, on the
    left of the centre line), ``near_finish`` (99 % round), ``off_track`` (all wheels off, past
    the outer border), ``reversed`` (the track driven the other way, car facing backwards),
    ``with_objects`` (three boxes ahead in alternating lanes). Raises ``ValueError`` for an
    unknown situation.
    """
    if situation not in SCENARIOS:
        raise ValueError(f"unknown situation {situation!r}; choose from {SCENARIOS}")
    objects: list[RaceObject] = []
    wheels = 4
    steering, speed, backwards = 0.0, 1.0, False
    if situation == "start_line":
        s, offset, steps, speed = 0.0, 0.0, 1, 0.1
    elif situation == "mid_lap":
        s, offset, steps, steering, speed = 0.5 * track.length, 0.1, 100, 15.0, 2.0
    elif situation == "near_finish":
        s, offset, steps, speed = 0.99 * track.length, -0.05, 200, 3.0
    elif situation == "off_track":
        s, steps, steering = 0.3 * track.length, 60, -30.0
        offset = -(float(track.widths[track.segment_at(s)]) / 2 + 0.4)
        wheels = 0
    elif situation == "reversed":
        track = track.reversed() if track.closed else track
        s, offset, steps, backwards = 0.25 * track.length, 0.0, 40, True
    else:  # with_objects
        s, offset, steps, speed = 0.1 * track.length, 0.0, 20, 1.5
        quarter = float(track.width) / 4
        for i, frac in enumerate((0.3, 0.55, 0.8)):
            ox, oy = track.point_at(frac * track.length, quarter if i % 2 == 0 else -quarter)
            objects.append(RaceObject(ox, oy, heading=track.heading_at(frac * track.length)))
    px, py = track.point_at(s, offset)
    yaw = track.heading_at(s) + (math.pi if backwards else 0.0)
    # The car's origin sits 0.14 m behind the reported point.
    pose = Pose(
        px - REPORTED_POINT_AHEAD_M * math.cos(yaw),
        py - REPORTED_POINT_AHEAD_M * math.sin(yaw),
        yaw,
        speed,
    )
    loc = track.locate(px, py)
    progress = 100.0 * (s % track.length) / track.length if track.closed else 100 * s / track.length
    return build_params(
        track=track,
        pose=pose,
        loc=loc,
        wheels_on_track=wheels,
        steering_angle=steering,
        speed=speed,
        progress=round(progress, 4),
        steps=steps,
        sim_time=steps / 15.0,
        objects=objects,
        object_in_camera=bool(objects),
    )
