"""One car's step on the track, written once: :class:`~racing.env.RacingEnv` and
:class:`~racing.headtohead.HeadToHeadRace` both drive their cars through it.

A step (:func:`drive`) is: the physics for 1/15 s, locating the reported point (0.14 m ahead
of the car's origin) on the centre line, counting the wheels on the track, asking the caller
whether the car crashed, and letting the car's :class:`~racing.rules.RaceTracker` judge it
(progress, laps, failures, penalties). A car's ``speed_multiplier`` (a race day's live speed
control, 0.5-1.5; 1.0 everywhere else) scales the commanded speed here, for the physics only,
clipped to the car's limits (:data:`~racing.car.MIN_SPEED`-:data:`~racing.car.MAX_SPEED`).
After a forgiven failure (``judged.reset``) the caller
calls :func:`respawn`, once it has read what it needs from the car where it was judged (the
env builds DeepRacer's ``params`` there). :func:`trace_row` writes the step's sim-trace row.

DeepRacer's respawn rules, for every caller:

- after running into a car (a bot, or another racer) the car stays where it is, at rest;
- after running into a box, or going off track, reversing or being immobilized, it goes to the
  spot the caller's world gives (1 m behind a nearby box, in the other lane; progress goes
  back with it), else to the nearer lane at the point where it failed, facing along the track.

What the caller keeps: moving the world (bots, the race clock), deciding what a contact is
(:meth:`racing.world.RaceWorld.crash`, the head-to-head rule), observations and rewards.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from racing.actions import ActionSpec
from racing.car import MAX_SPEED, MIN_SPEED, REPORTED_POINT_AHEAD_M, CarSim, Pose
from racing.objects import KIND_BOT, KIND_RACER, RaceObject
from racing.params import heading_deg
from racing.rules import Judgement, RaceTracker, Status
from racing.simtrace import TraceRow
from racing.track import Location, Track
from racing.world import Spot

STAY_AFTER_HITTING = frozenset({KIND_BOT, KIND_RACER})
"""Kinds of object that a car which ran into one is left beside, where it is, at rest."""


SpotFinder = Callable[[float], Spot | None]
"""Where a car respawning at ``s`` metres goes, or ``None`` for the nearer lane; called only
when the car does not stay where it is (:meth:`racing.world.RaceWorld.respawn_spot` counts)."""


class DrivenCar(Protocol):
    """What a step reads and writes on a car: its world and judge, and where it is."""

    sim: CarSim
    tracker: RaceTracker
    pose: Pose
    point: tuple[float, float]
    s: float
    hint: int | None
    speed_multiplier: float


@dataclass
class CarOnTrack:
    """A car on the track between steps (:class:`racing.racecar.RaceCar` has the same fields):
    ``pose`` of its origin, ``point`` the reported point (metres), ``s`` that point along the
    centre line (metres), ``hint`` the centre segment it was last found on;
    ``speed_multiplier`` scales the commanded speed (:func:`drive`)."""

    sim: CarSim
    tracker: RaceTracker
    pose: Pose = field(default_factory=lambda: Pose(0.0, 0.0, 0.0))
    point: tuple[float, float] = (0.0, 0.0)
    s: float = 0.0
    hint: int | None = None
    speed_multiplier: float = 1.0


@dataclass(frozen=True)
class Drive:
    """What one step did, read where the car was judged (before any respawn).

    ``steering`` (degrees) and ``speed`` (m/s) as commanded (the action's); ``multiplier`` the
    car's speed multiplier this step (it drove ``speed`` × ``multiplier``, clipped); ``loc``
    the reported point's location; ``wheels`` on the track, 0-4; ``crash`` the object the car
    ran into (a crash by the caller's rule) or ``None``; ``judged`` the tracker's judgement;
    ``yaw`` radians; ``progress`` percent of the lap after the step.
    """

    steering: float
    speed: float
    loc: Location
    wheels: int
    crash: RaceObject | None
    judged: Judgement
    point: tuple[float, float]
    yaw: float
    progress: float
    multiplier: float = 1.0


def place(car: DrivenCar, track: Track, s: float, offset: float = 0.0,
          yaw_offset: float = 0.0) -> Location:  # fmt: skip
    """Put the car at rest with its reported point ``offset`` metres left of the centre line at
    ``s`` metres, facing along the track turned by ``yaw_offset`` radians; where it now is."""
    px, py = track.point_at(s, offset)
    yaw = track.heading_at(s) + yaw_offset
    x = px - REPORTED_POINT_AHEAD_M * math.cos(yaw)
    y = py - REPORTED_POINT_AHEAD_M * math.sin(yaw)
    car.sim.place(x, y, yaw)
    car.pose = Pose(x, y, yaw)
    car.point = (px, py)
    loc = track.locate(px, py)
    car.hint, car.s = loc.segment, loc.s
    return loc


def drive(
    car: DrivenCar,
    track: Track,
    steering: float,
    speed: float,
    crash: Callable[[Location], RaceObject | None],
    asked: tuple[float, float] | None = None,
) -> Drive:
    """One 1/15 s step of ``car`` on ``track`` at the commanded ``steering`` (degrees) and
    ``speed`` (m/s), the speed scaled by ``car.speed_multiplier`` (:func:`driven_speed`).
    ``crash`` is asked, with the car already moved and located, what it ran
    into by the caller's rule (``None``: nothing). The caller moves its bots first.
    ``asked``: the ``(steering, speed)`` the model chose, where the car executed another
    command (the car and latency conditions); the step records it as its action."""
    old = car.point
    # The one place where the commanded action becomes the car's motion (RacingEnv and
    # HeadToHeadRace alike): the multiplier scales the physics' speed only.
    multiplier = float(car.speed_multiplier)
    car.pose = car.sim.step(steering, driven_speed(speed, multiplier))
    car.point = car.pose.point_ahead(REPORTED_POINT_AHEAD_M)
    loc = track.locate(car.point[0], car.point[1], car.hint)
    car.hint, car.s = loc.segment, loc.s
    wheels = wheels_on_track(track, car.pose)
    moved = math.hypot(car.point[0] - old[0], car.point[1] - old[1])
    hit = crash(loc)
    judged = car.tracker.update(
        s=loc.s, dt=car.sim.dt, moved_m=moved, wheels_on_track=wheels, crashed=hit is not None
    )
    if asked is not None:
        steering, speed = asked
    return Drive(steering, speed, loc, wheels, hit, judged, car.point, car.pose.yaw,
                 car.tracker.progress, multiplier)  # fmt: skip


def driven_speed(speed: float, multiplier: float) -> float:
    """The speed the car is driven at, m/s: ``speed`` × ``multiplier`` clipped to the car's
    limits, as DeepRacer's live speed control scaled the throttle; ``speed`` itself at 1.0."""
    if multiplier == 1.0:
        return speed
    return min(MAX_SPEED, max(MIN_SPEED, speed * multiplier))


def respawn(
    car: DrivenCar, track: Track, step: Drive, *, spot_near: SpotFinder | None = None
) -> None:
    """Put the car back after the forgiven failure of ``step`` (see the module's rules);
    ``spot_near`` gives the spot near boxes (``None``: no boxes, the nearer lane)."""
    loc = step.loc
    crash = step.crash if step.judged.status is Status.CRASHED else None
    if crash is not None and crash.kind in STAY_AFTER_HITTING:
        pose = car.pose
        car.sim.place(pose.x, pose.y, pose.yaw)
        car.pose = Pose(pose.x, pose.y, pose.yaw)
        car.tracker.respawned_at(loc.s)
        return
    spot = spot_near(loc.s) if spot_near is not None else None
    if spot is not None:
        new = place(car, track, spot.s, spot.offset)
        car.tracker.advance(new.s)  # progress goes back (or on) with the car
        return
    lane = track.width_at(loc) / 4
    new = place(car, track, loc.s, lane if loc.left else -lane)
    car.tracker.respawned_at(new.s)


def trace_row(
    car: DrivenCar,
    track: Track,
    step: Drive,
    *,
    episode: int,
    action: int | tuple[float, float],
    reward: float,
) -> TraceRow:
    """The step's sim-trace row, written after any respawn. ``X``, ``Y`` and ``yaw`` are where
    the car was judged, as SimApp logs the step that ended off track or in a crash, for every
    caller (the head-to-head race once wrote where a respawned car was put: one rule now).
    ``throttle`` is the action's speed; the multiplier the car drove with is ``step``'s
    (a race records it beside the trace). ``wall_clock`` is left 0 for whoever records the
    row (steps stay deterministic)."""
    judged = step.judged
    (x, y), yaw = step.point, step.yaw
    return TraceRow(
        episode=episode,
        steps=car.tracker.steps,
        x=x,
        y=y,
        yaw=heading_deg(yaw),
        steer=step.steering,
        throttle=step.speed,
        action=action,
        reward=reward,
        done=judged.done or judged.truncated,
        all_wheels_on_track=step.wheels == 4,
        progress=step.progress,
        closest_waypoint=closest_waypoint(track, step.loc),
        track_len=track.length,
        tstamp=car.tracker.sim_time,
        episode_status=judged.status.value,
        pause_duration=judged.penalty_s,
        obstacle_crash_counter=car.tracker.current_lap.crashes,
        wall_clock=0.0,
    )


def trace_action(
    actions: ActionSpec, action: object, decoded: tuple[float, float]
) -> int | tuple[float, float]:
    """The sim-trace's action column: the index, or the continuous pair driven (rounded)."""
    if actions.kind == "discrete":
        return int(np.asarray(action).reshape(-1)[0])
    return (round(decoded[0], 4), round(decoded[1], 4))


def wheels_on_track(track: Track, pose: Pose) -> int:
    """How many of the car's four wheel contacts lie on the track, 0-4."""
    xs, ys = pose.wheel_contacts()
    return int(np.count_nonzero(track.on_track(np.asarray(xs), np.asarray(ys))))


def closest_waypoint(track: Track, loc: Location) -> int:
    """The waypoint nearer to ``loc`` of the two around it (the sim-trace's column)."""
    behind, ahead = track.closest_waypoints(loc)
    return behind if loc.fraction < 0.5 else ahead
