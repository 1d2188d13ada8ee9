"""One racer's car in a head-to-head race (:mod:`racing.headtohead`): who it is, its world
and sensors, its judge and its record; and the start grid."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from racing.actions import ActionSpec
from racing.bodies import ObjectBodies
from racing.car import CarSim, Pose
from racing.lidar import LidarSensor
from racing.objects import BOT_HEIGHT_M, BOT_LENGTH_M, BOT_WIDTH_M, KIND_RACER, RaceObject
from racing.rules import LapRecord, RaceTracker, Status
from racing.sensors import CameraSensor
from racing.simtrace import TraceRow

MIN_RACERS, MAX_RACERS = 1, 4
"""One car alone is a time trial with the race's broadcast (a race day's solo run)."""
GRID_SPACING_M = 0.8
"""Distance along the centre line between two grid slots, metres (two car lengths)."""
RACER_COLOURS: tuple[tuple[int, int, int], ...] = (
    (214, 48, 49),
    (255, 176, 0),
    (46, 184, 92),
    (178, 76, 220),
)
"""The cars' colours on every camera and on the broadcast view, by entry order (RGB)."""
FOOTPRINT_AHEAD_M = 0.1
"""The centre of a car's footprint lies this far ahead of its origin (rear-axle middle), m."""


class CarState(str, Enum):
    """Where a car is in the race."""

    RACING = "racing"
    FINISHED = "finished"
    TIME_UP = "time_up"
    """Still on track when the race clock ran out."""
    OUT = "out"
    """Did not finish: out of resets, retired, or its policy failed (see ``reason``)."""


@dataclass(frozen=True)
class Racer:
    """One racer's car: its sensors and action space (``model_metadata.json``'s forms, as
    :class:`~racing.env.RacingEnv` takes them) and a name for people."""

    sensors: tuple[str, ...] = ("FRONT_FACING_CAMERA",)
    action_space: list | dict | None = None
    name: str = ""
    speed: Callable[[float], float] | None = field(default=None, compare=False, repr=False)
    """Live speed control (a race day's): called with the race clock (seconds) once per step
    the car drives, before it drives; the multiplier (0.5-1.5) for that step. None: 1.0."""


def grid_length_m(racers: int) -> float:
    """How far behind the start line the grid reaches, with a metre to spare: no bot starts
    there."""
    return (racers - 1) * GRID_SPACING_M + 1.0


def grid_order(racers: int, round_number: int) -> list[int]:
    """Entry indices in grid order for round ``round_number`` (0-based): round 0 puts entry 0
    on pole, and each later round moves everyone one slot forward, the pole sitter to the
    back, so over ``racers`` rounds everyone starts from every slot once."""
    if not MIN_RACERS <= racers <= MAX_RACERS:
        raise ValueError(f"a race has {MIN_RACERS} to {MAX_RACERS} cars, not {racers}")
    shift = round_number % racers
    return [(slot + shift) % racers for slot in range(racers)]


@dataclass
class RaceCar:
    """One racer's car in the race: its world, sensors, judge and record."""

    index: int
    racer: Racer
    colour: tuple[int, int, int]
    sim: CarSim
    bodies: ObjectBodies
    camera: CameraSensor
    lidar: LidarSensor | None
    actions: ActionSpec
    tracker: RaceTracker
    rng: np.random.Generator
    grid_slot: int = 0
    state: CarState = CarState.RACING
    reason: str = ""
    pose: Pose = field(default_factory=lambda: Pose(0.0, 0.0, 0.0))
    point: tuple[float, float] = (0.0, 0.0)
    s: float = 0.0
    hint: int | None = None
    finish_time_s: float | None = None
    rows: list[TraceRow] = field(default_factory=list)
    speed_multiplier: float = 1.0
    """The racer's live speed control (0.5-1.5, a race day's): the next step drives the
    action's speed times this (:func:`racing.carstep.drive`)."""
    speeds: list[float] = field(default_factory=list)
    """The multiplier of each step the car drove, one per trace row (the race's trace column)."""

    @property
    def on_track(self) -> bool:
        """Whether the car is still on the track (racing, or sitting out a penalty)."""
        return self.state is CarState.RACING

    @property
    def laps_done(self) -> int:
        return len(self.tracker.laps)

    def distance_m(self, track_length: float) -> float:
        """Distance covered in the race, metres (finished laps plus the current one)."""
        done = self.laps_done * track_length
        if self.state is CarState.FINISHED:
            return done
        return done + max(0.0, min(self.tracker.distance, track_length))

    def as_object(self) -> RaceObject:
        """This car as the others see it: a bot-sized body in its own colour."""
        c, s = math.cos(self.pose.yaw), math.sin(self.pose.yaw)
        return RaceObject(
            self.pose.x + FOOTPRINT_AHEAD_M * c,
            self.pose.y + FOOTPRINT_AHEAD_M * s,
            heading=self.pose.yaw,
            speed=max(0.0, self.pose.speed),
            length=BOT_LENGTH_M,
            width=BOT_WIDTH_M,
            height=BOT_HEIGHT_M,
            kind=KIND_RACER,
            colour=self.colour,
        )

    def lap_records(self) -> list[LapRecord]:
        """Every lap driven, the unfinished one last (with its time and progress so far)."""
        laps = list(self.tracker.laps)
        current = self.tracker.current_lap
        if self.state is not CarState.FINISHED and current not in laps:
            current.time_s = self.tracker.sim_time - self.tracker.lap_start_time
            current.progress = self.tracker.progress
            if self.state is CarState.TIME_UP and current.status is Status.IN_PROGRESS:
                current.status = Status.TIME_UP
            laps.append(current)
        return laps
