"""DeepRacer's reward-function input: the ``params`` dict, built from the simulator's state.

Every key of DeepRacer's ``params`` is present with DeepRacer's meaning and units, including the
four undocumented ones (``projection_distance``, ``objects_distance_from_center``,
``object_in_camera``, ``sim_time``). Object keys are present and empty in a time trial.

Units and conventions: ``x``, ``y`` metres at the point 0.14 m ahead of the car's origin;
``heading`` degrees in -180..180, counter-clockwise from +x; ``speed`` and ``steering_angle``
as commanded (m/s, degrees, positive = left); ``progress`` percent 0..100 from the episode's
start point; ``closest_waypoints`` ``[behind, ahead]``; ``is_left_of_center`` relative to the
driving direction; ``objects_heading`` in degrees (DeepRacer's documented unit; its simulator
passes radians). ``object_in_camera`` is computed by the caller (the env asks its camera).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

from racing.car import REPORTED_POINT_AHEAD_M, Pose
from racing.objects import KIND_BOT, RaceObject
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
    objects: Sequence[RaceObject] = (),
    object_locations: Sequence[Location] | None = None,
    object_in_camera: bool = False,
) -> dict:
    """The ``params`` dict for one step. ``loc`` locates the reported point (0.14 m ahead);
    ``object_locations`` (the objects located on ``track``) saves locating them again."""
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
        if object_locations is None:
            object_locations = [track.locate(o.x, o.y) for o in objects]
        _add_objects(params, loc, objects, object_locations)
    return params


def _add_objects(
    params: dict, car: Location, objects: Sequence[RaceObject], locs: Sequence[Location]
) -> None:
    """The object keys, as DeepRacer's ``get_object_reward_params`` fills them.

    ``objects_distance``: each object's projection on the centre line, metres from the start
    line in the driving direction. ``closest_objects``: ``[previous, next]`` by that distance
    around the car's own projection, wrapping round the list (so with one object both are 0).
    ``objects_left_of_center``: the object's side in the driving direction.
    ``objects_speed`` and ``objects_heading``: a bot's speed (m/s) and heading (degrees,
    -180..180); 0 for a box, as DeepRacer reports static obstacles.
    """
    bots = [o.kind == KIND_BOT for o in objects]
    params["objects_location"] = [[float(o.x), float(o.y)] for o in objects]
    params["objects_distance"] = [lo.s for lo in locs]
    params["objects_left_of_center"] = [lo.left for lo in locs]
    params["objects_speed"] = [
        float(o.speed) if bot else 0.0 for o, bot in zip(objects, bots, strict=True)
    ]
    params["objects_heading"] = [
        heading_deg(o.heading) if bot else 0.0 for o, bot in zip(objects, bots, strict=True)
    ]
    params["objects_distance_from_center"] = [lo.distance for lo in locs]
    params["closest_objects"] = list(closest_objects([lo.s for lo in locs], car.s))


def closest_objects(distances: Sequence[float], car_s: float) -> tuple[int, int]:
    """``(previous, next)`` object indices around ``car_s`` (DeepRacer's ``find_prev_next``):
    next is the first object strictly beyond the car along the centre line, wrapping to the
    first one past the start line; previous is the one before it."""
    order = sorted(range(len(distances)), key=distances.__getitem__)
    ordered = [distances[i] for i in order]
    nxt = bisect.bisect_right(ordered, car_s)
    prev = nxt - 1 if nxt > 0 else len(ordered) - 1
    nxt = nxt if nxt < len(ordered) else 0
    return order[prev], order[nxt]


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
