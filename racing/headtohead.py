"""Head-to-head races: 2-4 racers' cars, each driven by its own policy, on one track (or one
car alone: a time trial with the race's broadcast, as a race day runs them).

Each racer keeps its own sensors (camera, stereo, LIDAR) and action space, and sees the other
racers as it sees bot cars: in its cameras and in its LIDAR. The event's bot cars (head-to-bot
settings) drive among them. One clock runs for everyone at DeepRacer's 15 steps per simulated
second.

**Rules**, DeepRacer's head-to-bot rules for each car on its own (:mod:`racing.world`):

- Running into another racer or a bot from behind is a crash for the car behind; the car in
  front is not at fault and drives on (a bot that runs into a racer from behind stops the bots
  for :meth:`RaceRules.bot_pause` seconds instead).
- A crash, an off-track, reversing or being immobilized costs the car its penalty: it stands
  still for that many seconds of the race clock while everyone else drives on, then goes on from
  where it was (after a crash) or on the nearer lane at the point it left (after the others).
  Resets are counted per car against ``rules.resets``; a car out of resets is out of the race.
- A car that finishes its laps, retires (:meth:`HeadToHeadRace.retire`) or runs out of resets
  leaves the track at once: it blocks no one.
- The race ends when every car has finished or is out, or at ``time_limit_s`` of race clock.
- Bots start on the lap ahead of the grid, never on it (:func:`grid_length_m`).

**Start grid**: staggered, as DeepRacer's head-to-head races started: grid slot ``k`` is
``k`` × :data:`GRID_SPACING_M` behind the start line, alternating inner and outer lane, pole in
the inner lane. Each car's laps count from its own grid spot, so every car drives the same
distance. :func:`grid_order` rotates the grid between rounds so that everyone gets the pole.

**Live speed control** (DeepRacer's LIVE races): a :class:`Racer` with a ``speed`` callable
is asked its multiplier (0.5-1.5) once per step its car drives; the car drives its action's
speed times that (:func:`racing.carstep.drive`), and ``RaceCar.speeds`` keeps one per step.

**Determinism**: the same racers, actions and ``seed`` give the same race (the bots' lanes and
the LIDAR noise come from generators seeded with it; each car has its own PyBullet world).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from racing import carstep
from racing.actions import ActionSpaceError, ActionSpec
from racing.bodies import ObjectBodies
from racing.car import CarSim
from racing.conditioned_camera import conditioned
from racing.conditions import Conditions
from racing.lidar import LidarSensor
from racing.objects import BotFleet, Lanes, RaceObject
from racing.race import LANE_INNER, LANE_OUTER, RaceConfig, RaceType
from racing.racecar import (
    GRID_SPACING_M,
    MAX_RACERS,
    MIN_RACERS,
    RACER_COLOURS,
    CarState,
    RaceCar,
    Racer,
    grid_length_m,
    grid_order,
)
from racing.rules import LapRecord, RaceRules, RaceTracker, Status
from racing.sensors import CameraSensor, ground_for, validate_sensors
from racing.simtrace import TraceRow
from racing.timing import RaceTiming
from racing.track import Track, TrackError

__all__ = [
    "GRID_SPACING_M",
    "MAX_RACERS",
    "MIN_RACERS",
    "CarState",
    "HeadToHeadRace",
    "RaceCar",
    "Racer",
    "StepOutcome",
    "grid_length_m",
    "grid_order",
]
CAMERA_RESOLUTION_M = 0.005
CONDITIONS_STREAM = 0xC0D1
"""Mixed with the race's seed and the car's index into its camera's conditions generator."""


@dataclass(frozen=True)
class StepOutcome:
    """What one step of the race did to one car (``None`` for a car that did not drive)."""

    status: Status
    reset: bool
    penalty_s: float
    lap_finished: LapRecord | None
    done: bool
    trace: TraceRow


class HeadToHeadRace:
    """A race of 2-4 policy-driven cars (see the module docstring for the rules).

    ``track`` is a loop already in its driving direction; ``race`` is a time trial or a
    head-to-bot :class:`RaceConfig` (its bot cars join the race); ``rules`` gives the laps,
    resets and penalties (``rules.time_limit_s`` is the race's time limit, required);
    ``grid`` lists entry indices in grid order (default: entry order); ``conditions`` (a
    :class:`~racing.conditions.Conditions`) are applied to every car's camera (the light, look
    and camera families; the car and latency families are not applied here). Raises ``ValueError``
    for anything a race cannot run with.

    Drive it with :meth:`reset` (the first observations), then :meth:`step` with one action per
    car until :attr:`over`. An observation is what the car's :class:`~racing.env.RacingEnv`
    would give: the camera image, or a dict of camera and LIDAR; ``None`` for a car that does
    not act this step (finished, out, or sitting out a penalty).
    """

    def __init__(
        self,
        track: Track,
        racers: Sequence[Racer],
        *,
        rules: RaceRules,
        race: RaceConfig | None = None,
        seed: int = 0,
        grid: Sequence[int] | None = None,
        substeps: int = 4,
        conditions: Conditions | None = None,
    ) -> None:
        if not MIN_RACERS <= len(racers) <= MAX_RACERS:
            raise ValueError(f"a race has {MIN_RACERS} to {MAX_RACERS} cars, not {len(racers)}")
        if not track.closed:
            raise TrackError(f"track {track.name!r} is not a loop: head-to-head races need one")
        race = race or RaceConfig()
        if race.race_type is RaceType.OBJECT_AVOIDANCE:
            raise ValueError("a head-to-head race has bot cars or nothing else on the track")
        if rules.time_limit_s is None:
            raise ValueError("a head-to-head race needs a time limit (rules.time_limit_s)")
        grid = list(range(len(racers))) if grid is None else list(grid)
        if sorted(grid) != list(range(len(racers))):
            raise ValueError("grid must list every entry index once")
        self.track = track
        self.rules = rules
        self.time_limit_s = float(rules.time_limit_s)
        self.race = race
        self.seed = seed
        self.lanes = Lanes(track)
        self.clock_s = 0.0
        self.steps = 0
        self.timing = RaceTiming(track.length, rules.laps)
        """The race's timing, updated once a step (:meth:`reset`, :meth:`step`): positions,
        gaps, sectors; the broadcast and the results read it, nobody computes their own."""
        self.fleet: BotFleet | None = None
        if race.has_bots:
            self.fleet = BotFleet(track, self.lanes, race, np.random.default_rng(seed),
                                  keep_clear_m=grid_length_m(len(racers)))  # fmt: skip
        ground = ground_for(track, resolution=CAMERA_RESOLUTION_M, rgb=False)
        car_rules = replace(rules, time_limit_s=None)  # the race's clock, not each car's
        self.cars: list[RaceCar] = []
        for index, racer in enumerate(racers):
            sensors = validate_sensors(list(racer.sensors))
            sim = CarSim(substeps=substeps)
            self.cars.append(
                RaceCar(
                    index=index,
                    racer=racer,
                    colour=RACER_COLOURS[index],
                    sim=sim,
                    bodies=ObjectBodies(sim),
                    camera=conditioned(  # every car's camera sees the same conditions
                        CameraSensor(ground, sensors[0]),
                        track,
                        conditions,
                        np.random.default_rng([seed, index, CONDITIONS_STREAM]),
                    ),  # fmt: skip
                    lidar=LidarSensor(sensors[1]) if len(sensors) > 1 else None,
                    actions=ActionSpec.parse(racer.action_space),
                    tracker=RaceTracker(car_rules, track.length, closed=True),
                    rng=np.random.default_rng([seed, index]),
                    grid_slot=grid.index(index),
                )
            )

    # ------------------------------------------------------------------ driving
    @property
    def bots(self) -> tuple[RaceObject, ...]:
        return self.fleet.objects if self.fleet is not None else ()

    @property
    def over(self) -> bool:
        """Every car finished or out, or the race clock ran out."""
        return not any(car.on_track for car in self.cars)

    def reset(self) -> list[object | None]:
        """Put every car on its grid slot at rest; the first observation of each car."""
        for car in self.cars:
            slot = car.grid_slot
            s = (-slot * GRID_SPACING_M) % self.track.length
            lane = LANE_INNER if slot % 2 == 0 else LANE_OUTER
            carstep.place(car, self.track, s, self.lanes.offset(s, lane))
            car.tracker.start(car.s)
        self.timing = RaceTiming(self.track.length, self.rules.laps)
        self.timing.update(self)
        return self.observations()

    def step(self, actions: Sequence[object | None]) -> list[StepOutcome | None]:
        """One 1/15 s step of the race clock: every car on track and not sitting out a penalty
        drives its action (the others' entries are ignored). A car whose action is outside its
        action space is retired with the reason; the race goes on."""
        if len(actions) != len(self.cars):
            raise ValueError(f"one action per car: {len(self.cars)} expected")
        dt = self.cars[0].sim.dt
        decoded: dict[int, tuple[float, float]] = {}
        chosen: dict[int, int | tuple[float, float]] = {}
        for car in self.cars:
            if not self._drives(car):
                continue
            try:
                decoded[car.index] = car.actions.decode(actions[car.index])
                chosen[car.index] = carstep.trace_action(car.actions, actions[car.index],
                                                         decoded[car.index])  # fmt: skip
            except ActionSpaceError as exc:
                self.retire(car.index, f"its policy chose an impossible action: {exc}")
        driving = [car for car in self.cars if car.index in decoded]
        self.steps += 1
        self.clock_s += dt
        if self.fleet is not None:
            self.fleet.advance(dt)
        for car in driving:  # everyone sees where the others were before this step
            car.bodies.sync(self._objects_for(car))
        outcomes: list[StepOutcome | None] = [None] * len(self.cars)
        for car in driving:
            outcomes[car.index] = self._drive(car, *decoded[car.index], chosen[car.index])
        if self.clock_s >= self.time_limit_s - 1e-9:
            for car in self.cars:
                if car.on_track:
                    car.state = CarState.TIME_UP
        self.timing.update(self)
        return outcomes

    def retire(self, index: int, reason: str) -> None:
        """Take car ``index`` out of the race (its policy failed, its racer withdrew)."""
        car = self.cars[index]
        if car.on_track:
            car.state = CarState.OUT
            car.reason = reason
            if self.timing.latest is not None:  # the tower shows it out from now on
                self.timing.update(self)

    def observations(self) -> list[object | None]:
        """What each car that acts next step sees now; ``None`` for the others."""
        return [self._observe(car) if self._drives(car) else None for car in self.cars]

    def objects(self) -> tuple[RaceObject, ...]:
        """The bots and every car still on track, as bodies (for pictures)."""
        return (*self.bots, *(car.as_object() for car in self.cars if car.on_track))

    def standings(self) -> list[RaceCar]:
        """The cars in race order, as the timing tower shows them: :attr:`timing`'s positions
        (:class:`~racing.timing.RaceTiming`'s rule and tie-breaks, the one place that decides
        positions), as of the last step."""
        latest = self.timing.latest or self.timing.update(self)
        return [self.cars[line.index] for line in latest.cars]

    def close(self) -> None:
        for car in self.cars:
            car.sim.close()

    # ------------------------------------------------------------------ internals
    def _drives(self, car: RaceCar) -> bool:
        """On track and not sitting out a penalty (its clock already holds the penalty)."""
        return car.on_track and car.tracker.sim_time <= self.clock_s + 1e-9

    def _others(self, car: RaceCar) -> list[RaceCar]:
        return [other for other in self.cars if other.on_track and other is not car]

    def _objects_for(self, car: RaceCar) -> tuple[RaceObject, ...]:
        """What ``car`` sees and can touch: the bots, then the other cars on track."""
        return (*self.bots, *(other.as_object() for other in self._others(car)))

    def _observe(self, car: RaceCar) -> object:
        objects = self._objects_for(car)
        image = car.camera.observe(car.pose, objects)
        if car.lidar is None:
            return image
        reading = car.lidar.observe(car.pose, objects, car.rng)
        return {car.racer.sensors[0]: image, car.racer.sensors[1]: reading}

    def _drive(
        self, car: RaceCar, steering: float, speed: float, action: int | tuple[float, float]
    ) -> StepOutcome:
        if car.racer.speed is not None:  # live speed control: read once a step, from now on
            car.speed_multiplier = float(car.racer.speed(self.clock_s))
        step = carstep.drive(car, self.track, steering, speed, lambda loc: self._crashed(car))
        judged = step.judged
        if judged.reset:
            carstep.respawn(car, self.track, step)
        finished = car.tracker.laps[-1] if judged.lap_finished else None
        if judged.done or judged.truncated:
            if judged.status is Status.LAP_COMPLETE:
                car.state = CarState.FINISHED
                car.finish_time_s = car.tracker.sim_time
            elif judged.truncated:
                car.state, car.reason = CarState.TIME_UP, "lap time limit"
            else:
                car.state, car.reason = CarState.OUT, f"{judged.status.label}, no resets left"
        trace = carstep.trace_row(car, self.track, step, episode=0, action=action, reward=0.0)
        car.speeds.append(step.multiplier)
        return StepOutcome(
            judged.status, judged.reset, judged.penalty_s, finished, not car.on_track, trace
        )

    def _crashed(self, car: RaceCar) -> RaceObject | None:
        """DeepRacer's rule: touching a bot or a racer is a crash for the one behind; what
        ``car`` ran into, or ``None``."""
        index = car.bodies.touching()
        if index is None:
            return None
        bots = self.bots
        if index >= len(bots):  # another racer: compare the same reported points
            other = self._others(car)[index - len(bots)]
            return other.as_object() if self._gap_ahead(car.s, other.s) > 0.0 else None
        bot = bots[index]
        if self._gap_ahead(car.s, self.track.locate(bot.x, bot.y).s) > 0.0:
            return bot
        assert self.fleet is not None
        pause = self.rules.bot_pause()
        if not self.fleet.paused and pause > 0.0:
            self.fleet.pause(pause)
        return None

    def _gap_ahead(self, car_s: float, other_s: float) -> float:
        """Centre-line distance from ``car_s`` forward to ``other_s``, -L/2..L/2, metres."""
        half = self.track.length / 2
        return (other_s - car_s + half) % self.track.length - half
