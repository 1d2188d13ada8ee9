"""The race's timing, computed once per step and handed on as plain data: the broadcast page's
HTML tower, the websocket JSON and the MP4 replay's burnt-in tower all render from it (no other
code works out positions or gaps).

**Timing lines.** As at DeepRacer's races, a lap is cut into :data:`SECTORS` sectors of equal
length; each car's laps count from its own grid spot (:mod:`racing.headtohead`), so line ``n``
(0 the start, then one every third of a lap) lies ``n × L / 3`` metres into *that car's* race.
:meth:`RaceTiming.record` notes the race clock when each car first crosses each line
(interpolated between the two steps around it). From those crossings:

- a sector time is the time between two lines (penalties included: a car sitting one out stands
  still while the clock runs);
- the **gap** of a car to the leader, and its **interval** to the car ahead, are measured at
  the last line the car crossed: its crossing time minus theirs (``None`` before the first
  line, and for a car that is out). A car that crossed that line *first* but is behind on
  distance now (it was passed since, or a staggered grid) gets instead the time since the car
  ahead was where it is now (interpolated on the car ahead's path), never a ``+0.0``;
- **positions**: finishers by finishing time; then cars still racing (or stopped by the time
  limit) by distance covered; then cars out, by distance. Ties go to whoever crossed the last
  common line first, then to the better grid slot.

:meth:`RaceTiming.update` reads a :class:`~racing.headtohead.HeadToHeadRace` (duck-typed: the
cars' laps, distance, penalties, state); :meth:`RaceTiming.record` takes plain
:class:`CarReading` values (what the tests give by hand). :meth:`Timing.to_dict` is JSON-able
and carries what a spectator may see: names, colours, times, positions; no model ids, and a
retirement reason only as a short public label (:func:`public_reason`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

SECTORS = 3
RACING, FINISHED, TIME_UP, RETIRED = "racing", "finished", "time_up", "retired"
PURPLE, GREEN, YELLOW = "purple", "green", "yellow"
CRASH, OFF_TRACK = "crash", "off_track"


@dataclass(frozen=True)
class CarReading:
    """One car after a step, as the timing reads it.

    ``distance_m`` covered in the race from its grid spot; ``state`` one of ``racing``,
    ``finished``, ``time_up``, ``retired``; ``lap_times_s`` of its finished laps (penalties
    in); ``penalties`` and ``penalty_s`` so far; ``crashes`` and ``off_tracks`` so far (an
    increase is an incident for :mod:`racing.director`)."""

    index: int
    name: str
    distance_m: float
    state: str = RACING
    laps_done: int = 0
    lap_times_s: tuple[float, ...] = ()
    finish_time_s: float | None = None
    reason: str = ""
    penalties: int = 0
    penalty_s: float = 0.0
    crashes: int = 0
    off_tracks: int = 0
    grid_slot: int = 0
    colour: tuple[int, int, int] = (200, 200, 200)
    speed_multiplier: float = 1.0


@dataclass(frozen=True)
class CarTiming:
    """One car's line on the timing tower."""

    index: int
    name: str
    colour: str
    position: int
    status: str
    reason: str
    lap: int
    laps_done: int
    distance_m: float
    lines: int
    gap_s: float | None
    interval_s: float | None
    last_lap_s: float | None
    best_lap_s: float | None
    sectors: list[float]
    sector_colours: list[str]
    penalties: int
    penalty_s: float
    finish_s: float | None
    speed_multiplier: float

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "name": self.name,
            "colour": self.colour,
            "position": self.position,
            "status": self.status,
            "reason": self.reason,
            "lap": self.lap,
            "laps_done": self.laps_done,
            "gap_s": _r(self.gap_s, 3),
            "interval_s": _r(self.interval_s, 3),
            "last_lap_s": _r(self.last_lap_s, 3),
            "best_lap_s": _r(self.best_lap_s, 3),
            "sectors": [round(t, 2) for t in self.sectors],
            "sector_colours": list(self.sector_colours),
            "penalties": self.penalties,
            "penalty_s": round(self.penalty_s, 1),
            "finish_s": _r(self.finish_s, 3),
            "speed_multiplier": round(self.speed_multiplier, 2),
        }


@dataclass(frozen=True)
class Incident:
    """A car crashed or went off track on this step (``kind``: :data:`CRASH`, :data:`OFF_TRACK`)."""

    car: int
    kind: str


@dataclass(frozen=True)
class Timing:
    """The race's timing after one step (cars in position order)."""

    clock_s: float
    laps: int
    lap: int
    over: bool
    cars: list[CarTiming]
    winner: CarTiming | None
    incidents: list[Incident] = field(default_factory=list)

    def car(self, index: int) -> CarTiming | None:
        return next((c for c in self.cars if c.index == index), None)

    def to_dict(self) -> dict:
        winner = self.winner
        return {
            "clock_s": round(self.clock_s, 2),
            "laps": self.laps,
            "lap": self.lap,
            "over": self.over,
            "sectors": SECTORS,
            "winner": None
            if winner is None
            else {"index": winner.index, "name": winner.name, "time_s": _r(winner.finish_s, 3)},
            "cars": [car.to_dict() for car in self.cars],
        }


def _r(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def hex_colour(rgb: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb))


def public_reason(reason: str) -> str:
    """A retirement reason as spectators may read it: a short label, never the error text."""
    text = reason.lower()
    if "no resets left" in text:
        return reason.split(",")[0].strip()[:24] + ", no resets left"
    if "withdr" in text:
        return "withdrawn"
    if "policy" in text or "checkpoint" in text or "model" in text or "metadata" in text:
        return "car failure"
    return "retired"


class RaceTiming:
    """The timing of one race: call :meth:`update` (or :meth:`record`) once per step."""

    def __init__(self, track_length: float, laps: int) -> None:
        if track_length <= 0 or laps < 1:
            raise ValueError("timing needs a positive track length and at least one lap")
        self.track_length = float(track_length)
        self.laps = int(laps)
        self.line_m = self.track_length / SECTORS
        self.crossings: dict[int, list[float]] = {}
        """Race clock when each car crossed each line (index 0: the start, at 0 s)."""
        self._last: dict[int, tuple[float, float]] = {}
        self._path: dict[int, tuple[list[float], list[float]]] = {}
        """Each car's distance (increasing) and the race clock it got there, for the gaps."""
        self._clock = 0.0
        self._incidents: dict[int, tuple[int, int]] = {}
        self.latest: Timing | None = None

    # ------------------------------------------------------------------ reading a race
    def update(self, race) -> Timing:
        """Read ``race`` (a :class:`~racing.headtohead.HeadToHeadRace`) after a step."""
        return self.record(race.clock_s, [read_car(car, self.track_length) for car in race.cars],
                           over=race.over)  # fmt: skip

    # ------------------------------------------------------------------ the model
    def record(self, clock_s: float, cars: list[CarReading], *, over: bool = False) -> Timing:
        """The timing after the step that ended at ``clock_s`` with the cars as read."""
        incidents = []
        self._clock = clock_s
        for car in cars:
            self._cross(car, clock_s)
            before = self._incidents.get(car.index, (car.crashes, car.off_tracks))
            if car.crashes > before[0]:
                incidents.append(Incident(car.index, CRASH))
            elif car.off_tracks > before[1]:
                incidents.append(Incident(car.index, OFF_TRACK))
            self._incidents[car.index] = (car.crashes, car.off_tracks)
        order = sorted(cars, key=self._order_key)
        sectors = {car.index: self._sectors(car.index) for car in cars}
        colours = _sector_colours(sectors, self.crossings)
        lines: list[CarTiming] = []
        leader = order[0] if order else None
        for position, car in enumerate(order, start=1):
            ahead = order[position - 2] if position > 1 else None
            lines.append(
                CarTiming(
                    index=car.index,
                    name=car.name or f"Car {car.index + 1}",
                    colour=hex_colour(car.colour),
                    position=position,
                    status=car.state,
                    reason=public_reason(car.reason) if car.state == RETIRED else "",
                    lap=min(self.laps, car.laps_done + (car.state != FINISHED)),
                    laps_done=car.laps_done,
                    distance_m=car.distance_m,
                    lines=len(self.crossings[car.index]) - 1,
                    gap_s=self._gap(car, leader) if position > 1 else None,
                    interval_s=self._gap(car, ahead) if ahead is not None else None,
                    last_lap_s=car.lap_times_s[-1] if car.lap_times_s else None,
                    best_lap_s=min(car.lap_times_s) if car.lap_times_s else None,
                    sectors=sectors[car.index],
                    sector_colours=colours[car.index],
                    penalties=car.penalties,
                    penalty_s=car.penalty_s,
                    finish_s=car.finish_time_s if car.state == FINISHED else None,
                    speed_multiplier=float(car.speed_multiplier),
                )
            )
        lead = lines[0] if lines else None
        lap = 0
        if lead is not None:
            lap = max((c.lap for c in lines if c.status in (RACING, FINISHED)), default=lead.lap)
        winner = None
        if (
            over
            and lead is not None
            and (lead.status == FINISHED or (lead.status == TIME_UP and lead.distance_m > 0))
        ):
            winner = lead
        self.latest = Timing(clock_s=clock_s, laps=self.laps, lap=lap, over=over, cars=lines,
                             winner=winner, incidents=incidents)  # fmt: skip
        return self.latest

    def _cross(self, car: CarReading, clock_s: float) -> None:
        crossed = self.crossings.setdefault(car.index, [0.0])
        prev_clock, prev_d = self._last.get(car.index, (0.0, 0.0))
        last_line = SECTORS * self.laps
        while len(crossed) <= last_line:
            line_d = len(crossed) * self.line_m
            if car.distance_m + 1e-9 < line_d and not (
                car.state == FINISHED and len(crossed) == last_line
            ):
                break
            span = car.distance_m - prev_d
            if car.state == FINISHED and len(crossed) == last_line and car.finish_time_s:
                at = car.finish_time_s
            elif span > 1e-9 and prev_d <= line_d:
                at = prev_clock + (clock_s - prev_clock) * (line_d - prev_d) / span
            else:
                at = clock_s
            crossed.append(max(crossed[-1], min(clock_s, at)))
        if car.distance_m > prev_d or car.index not in self._last:
            self._last[car.index] = (clock_s, car.distance_m)
        else:
            self._last[car.index] = (clock_s, prev_d)
        distances, clocks = self._path.setdefault(car.index, ([0.0], [0.0]))
        if car.distance_m > distances[-1]:
            distances.append(car.distance_m)
            clocks.append(clock_s)

    def _time_at(self, index: int, distance_m: float) -> float | None:
        """When car ``index`` first got ``distance_m`` into its race (interpolated), or None."""
        distances, clocks = self._path.get(index, ([0.0], [0.0]))
        at = bisect.bisect_left(distances, distance_m)
        if at >= len(distances):
            return None
        if at == 0 or distances[at] == distance_m:
            return clocks[at]
        d0, d1, t0, t1 = distances[at - 1], distances[at], clocks[at - 1], clocks[at]
        return t0 + (t1 - t0) * (distance_m - d0) / (d1 - d0)

    def _order_key(self, car: CarReading) -> tuple:
        crossed = self.crossings[car.index]
        last_line_at = crossed[-1] if len(crossed) > 1 else math.inf
        if car.state == FINISHED:
            return (0, car.finish_time_s or 0.0, car.grid_slot)
        group = 2 if car.state == RETIRED else 1
        return (group, -round(car.distance_m, 6), -(len(crossed) - 1), last_line_at,
                car.grid_slot)  # fmt: skip

    def _gap(self, car: CarReading, other: CarReading | None) -> float | None:
        """Seconds ``car`` is behind ``other`` at the last line ``car`` crossed."""
        if other is None or car.state == RETIRED:
            return None
        mine, theirs = self.crossings[car.index], self.crossings[other.index]
        line = len(mine) - 1
        if line < 1:
            return None
        if line >= len(theirs):  # other is behind on the road (only when out): no gap
            return None
        gap = mine[line] - theirs[line]
        if gap <= 0.0 and other.distance_m > car.distance_m:
            # ``car`` crossed the line first but is behind now: how long ago ``other`` was here
            there = self._time_at(other.index, car.distance_m)
            if there is not None:
                return max(0.0, self._clock - there)
        return max(0.0, gap)

    def _sectors(self, index: int) -> list[float]:
        """Sector times of the lap being driven, or of the last lap when none is done yet."""
        crossed = self.crossings[index]
        lines = len(crossed) - 1
        lap_start = (lines // SECTORS) * SECTORS
        if lines % SECTORS == 0 and lines > 0:
            lap_start -= SECTORS  # at a lap's line: the lap just finished
        return [crossed[i + 1] - crossed[i] for i in range(lap_start, min(lines, lap_start + 3))]


def _sector_colours(sectors: dict[int, list[float]], crossings: dict[int, list[float]]
                    ) -> dict[int, list[str]]:  # fmt: skip
    """Motor racing's colours: ``purple`` the session's best in that sector, ``green`` the
    car's own best, ``yellow`` slower."""
    own: dict[int, list[float]] = {}
    for index, crossed in crossings.items():
        best = [math.inf] * SECTORS
        for line in range(1, len(crossed)):
            sector = (line - 1) % SECTORS
            best[sector] = min(best[sector], crossed[line] - crossed[line - 1])
        own[index] = best
    session = [min((own[i][s] for i in own), default=math.inf) for s in range(SECTORS)]
    colours = {}
    for index, times in sectors.items():
        row = []
        for s, t in enumerate(times):
            if t <= session[s] + 1e-9:
                row.append(PURPLE)
            elif t <= own[index][s] + 1e-9:
                row.append(GREEN)
            else:
                row.append(YELLOW)
        colours[index] = row
    return colours


STATE_NAMES = {"racing": RACING, "finished": FINISHED, "time_up": TIME_UP, "out": RETIRED}


def read_car(car, track_length: float) -> CarReading:
    """A :class:`~racing.racecar.RaceCar` as the timing reads it."""
    tracker = car.tracker
    records = list(tracker.laps)
    current = tracker._lap
    if current is not None and all(current is not lap for lap in records):
        records.append(current)
    done = [lap.time_s for lap in tracker.laps]
    state = STATE_NAMES.get(getattr(car.state, "value", car.state), RACING)
    return CarReading(
        index=car.index,
        name=car.racer.name,
        distance_m=car.distance_m(track_length),
        state=state,
        laps_done=len(done),
        lap_times_s=tuple(done),
        finish_time_s=car.finish_time_s,
        reason=car.reason,
        penalties=sum(lap.resets for lap in records),
        penalty_s=sum(lap.penalty_s for lap in records),
        crashes=sum(lap.crashes for lap in records),
        off_tracks=sum(lap.off_tracks for lap in records),
        grid_slot=car.grid_slot,
        colour=tuple(car.colour),
        speed_multiplier=float(getattr(car, "speed_multiplier", 1.0)),
    )
