"""One racer's car in a head-to-head race (:mod:`racing.headtohead`): who it is, its world
and sensors, its judge and its record; and the start grid."""

from __future__ import annotations

import math
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
SECTORS = 3
"""A lap is timed in three sectors, as motor racing's timing screens show it."""
PURPLE, GREEN, YELLOW = "purple", "green", "yellow"
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
    sectors: list[list[float]] = field(default_factory=list)
    """Sector times of each finished lap (:data:`SECTORS` a lap), seconds, penalties in."""
    lap_sectors: list[float] = field(default_factory=list)
    """Sector times of the lap being driven so far."""

    def time_sectors(self, finished: LapRecord | None) -> None:
        """After a step: close the sector the car just left, or the lap it just finished."""
        tracker = self.tracker
        if finished is not None:
            times = self.lap_sectors
            while len(times) < SECTORS - 1:  # a lap cut short of a boundary: split what is left
                times.append(0.0)
            times.append(max(0.0, finished.time_s - sum(times)))
            self.sectors.append(times)
            self.lap_sectors = []
            return
        done = len(self.lap_sectors)
        if done < SECTORS - 1 and tracker.progress >= 100.0 * (done + 1) / SECTORS:
            elapsed = tracker.sim_time - tracker.lap_start_time
            self.lap_sectors.append(max(0.0, elapsed - sum(self.lap_sectors)))

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


def sector_colours(cars: list[RaceCar]) -> dict[int, list[str]]:
    """Motor racing's colours of each car's latest sector times (its lap being driven, else its
    last lap), by car index: ``purple`` for the session's best in that sector, ``green`` for
    the car's own best, ``yellow`` for slower."""
    best = [min((lap[i] for car in cars for lap in car.sectors if lap[i] > 0), default=None)
            for i in range(SECTORS)]  # fmt: skip
    best = [min((t for t in (b, *(c.lap_sectors[i] for c in cars if len(c.lap_sectors) > i))
                 if t), default=None) for i, b in enumerate(best)]  # fmt: skip
    colours: dict[int, list[str]] = {}
    for car in cars:
        shown = car.lap_sectors or (car.sectors[-1] if car.sectors else [])
        history = [*car.sectors, car.lap_sectors]
        own = [min((lap[i] for lap in history if len(lap) > i and lap[i] > 0), default=None)
               for i in range(SECTORS)]  # fmt: skip
        row = []
        for i, value in enumerate(shown):
            if value > 0 and best[i] is not None and value <= best[i] + 1e-9:
                row.append(PURPLE)
            elif value > 0 and own[i] is not None and value <= own[i] + 1e-9:
                row.append(GREEN)
            else:
                row.append(YELLOW)
        colours[car.index] = row
    return colours
