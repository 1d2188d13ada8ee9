"""The objects of one environment through an episode: placing them, moving the bots, telling a
crash from a harmless touch, and where a car starts or respawns near them.

DeepRacer's rules (SimApp's ``rollout_agent_ctrl`` and ``bot_cars_agent_ctrl``):

- Touching a box is always a crash. Touching a bot car is a crash only when the car is behind
  the bot (it ran into it); when a bot runs into the car from behind, the bots stop for
  :attr:`RaceWorld.bot_pause_s` seconds instead and the car is not at fault.
- While the car sits out a penalty, the world goes on: the bots keep driving.
- A car that starts an episode within :data:`CLOSEST_OBJECT_GAP_M` of an object starts in the
  other lane.
- A car respawned within :data:`CLOSEST_OBJECT_GAP_M` of a box is put
  :data:`RESET_BEHIND_M` behind it, in the other lane (optionally, after a number of such
  respawns in a row at the same box, :data:`RESET_AHEAD_M` past it: the "mercy reset").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from racing.bodies import ObjectBodies
from racing.car import CarSim
from racing.objects import KIND_BOT, BotFleet, Lanes, RaceObject, place_boxes
from racing.race import RaceConfig
from racing.rules import RaceRules
from racing.track import Location, Track

CLOSEST_OBJECT_GAP_M = 1.0
"""An object this close along the centre line moves a start or a respawn, metres."""
RESET_BEHIND_M = 1.0
"""A car respawned near a box is put this far behind it, metres."""
CAR_REACH_M = 0.4
"""Every part of the car lies within this distance of its origin (rear-axle middle), metres."""
RESET_AHEAD_M = 1.0
"""A mercy reset puts the car this far past the box it is stuck behind, metres."""


@dataclass(frozen=True, slots=True)
class Spot:
    """A place on the track: ``s`` metres along the centre line, ``offset`` metres left of it."""

    s: float
    offset: float


class RaceWorld:
    """This env's boxes or bot cars, in the car's PyBullet world."""

    def __init__(self, sim: CarSim, config: RaceConfig, rules: RaceRules) -> None:
        self.config = config
        self.bot_pause_s = rules.bot_pause()
        self.mercy_resets = rules.mercy_resets
        self._stuck: tuple[int | None, int] = (None, 0)
        """The box the last respawns were behind, and how many in a row."""
        self.bodies = ObjectBodies(sim)
        self._lanes: dict[int, Lanes] = {}
        self._boxes: tuple[RaceObject, ...] = ()
        self.fleet: BotFleet | None = None
        self.track: Track | None = None
        self.locations: tuple[Location, ...] = ()
        """Every object located on the track (same order as :attr:`objects`)."""

    @property
    def objects(self) -> tuple[RaceObject, ...]:
        """Every object now, in params order: the boxes, or the bot cars."""
        return self.fleet.objects if self.fleet is not None else self._boxes

    def lanes(self, track: Track) -> Lanes:
        """The lanes of ``track`` (one driving direction), measured once."""
        lanes = self._lanes.get(id(track))
        if lanes is None:
            lanes = self._lanes[id(track)] = Lanes(track)
        return lanes

    def reset(self, track: Track, rng: np.random.Generator) -> None:
        """Place this episode's objects on ``track`` (already in the driving direction).
        Raises ``ValueError`` when the configured objects do not fit on the track."""
        self.track = track
        lanes = self.lanes(track)
        self.fleet = None
        self._boxes = ()
        self._stuck = (None, 0)
        if self.config.has_boxes:
            self._boxes = place_boxes(track, lanes, self.config, rng)
        elif self.config.has_bots:
            self.fleet = BotFleet(track, lanes, self.config, rng)
        self.bodies.sync(self.objects)
        self._locate()

    def advance(self, seconds: float) -> None:
        """Move the bots on by ``seconds`` of simulated time and their bodies with them."""
        if self.fleet is not None and self.track is not None:
            self.fleet.advance(seconds)
            self.bodies.sync(self.fleet.objects)
            self._locate()

    def _locate(self) -> None:
        """Project every object on the centre line (for params, starts and respawns)."""
        objects = self.objects
        if self.track is None or not objects:
            self.locations = ()
            return
        xs = [o.x for o in objects]
        ys = [o.y for o in objects]
        self.locations = tuple(self.track.locate_all(xs, ys))

    def crash(self, car_s: float, car_xy: tuple[float, float]) -> RaceObject | None:
        """The object the car crashed into in the last physics step by DeepRacer's rules, or
        ``None``; a bot that hit the car from behind is paused instead. ``car_s`` is the car's
        reported point along the centre line and ``car_xy`` its origin, metres. PyBullet is
        asked for contacts only when an object is within reach of the car."""
        x, y = car_xy
        if all(
            math.hypot(o.x - x, o.y - y) > CAR_REACH_M + math.hypot(o.length, o.width) / 2
            for o in self.objects
        ):
            return None
        index = self.bodies.touching()
        if index is None:
            return None
        obj = self.objects[index]
        if obj.kind != KIND_BOT or self._gap_ahead(car_s, index) > 0.0:
            return obj
        assert self.fleet is not None
        if not self.fleet.paused and self.bot_pause_s > 0.0:
            self.fleet.pause(self.bot_pause_s)
        return None

    def _gap_ahead(self, car_s: float, index: int) -> float:
        """Centre-line distance from the car forward to object ``index``, -L/2..L/2 on a loop,
        metres."""
        assert self.track is not None
        gap = self.locations[index].s - car_s
        if self.track.closed:
            half = self.track.length / 2
            gap = (gap + half) % self.track.length - half
        return gap

    def _nearest(self, s: float, *, boxes_only: bool = False) -> int | None:
        """Index of the object nearest to ``s`` along the centre line within
        :data:`CLOSEST_OBJECT_GAP_M`, or ``None``."""
        near = [
            (abs(self._gap_ahead(s, i)), i)
            for i, o in enumerate(self.objects)
            if not (boxes_only and o.kind == KIND_BOT)
        ]
        near = [item for item in near if item[0] < CLOSEST_OBJECT_GAP_M]
        return min(near)[1] if near else None

    def _other_lane(self, index: int, s: float) -> float:
        """Offset (metres left) at ``s`` of the lane that object ``index`` is not in."""
        assert self.track is not None
        lanes = self.lanes(self.track)
        loc = self.locations[index]
        lane = lanes.lane_of(loc.distance if loc.left else -loc.distance)
        return lanes.offset(s, -lane)

    def start_offset(self, s: float) -> float | None:
        """Offset for a car starting at ``s`` next to an object, else ``None`` (no change)."""
        index = self._nearest(s)
        return None if index is None else self._other_lane(index, s)

    def respawn_spot(self, s: float) -> Spot | None:
        """Where a car respawning at ``s`` goes when a box is close, else ``None``.

        With :attr:`mercy_resets` set, the car respawned that many times in a row at the same
        box is put :data:`RESET_AHEAD_M` past it instead (SimApp's optional mercy reset).
        """
        index = self._nearest(s, boxes_only=True)
        if index is None:
            return None
        assert self.track is not None
        self._stuck = (index, self._stuck[1] + 1 if self._stuck[0] == index else 1)
        spot_s = self.locations[index].s - RESET_BEHIND_M
        if self.mercy_resets is not None and self._stuck[1] >= self.mercy_resets:
            spot_s = self.locations[index].s + RESET_AHEAD_M
            self._stuck = (None, 0)
        if self.track.closed:
            spot_s %= self.track.length
        return Spot(spot_s, self._other_lane(index, spot_s))
