"""Boxes and bot cars on the track: where they go and how the bots drive.

Everything here is plain geometry on a :class:`Track`; the PyBullet bodies that the car
collides with live in :mod:`racing.bodies`. Lanes are DeepRacer's: the midlines between the
centre line and each border, lane 1 the inner one and lane -1 the outer one (on a loop "inner"
is the border nearer the loop's middle, whichever way the car drives).

Placement follows DeepRacer's simulator (SimApp): without fixed positions, objects are spread
evenly from a minimum gap after the start line to :data:`END_MARGIN_M` before the end of the
lap, lanes alternating inner first; randomized placement visits the objects in random order and
moves each one uniformly between its neighbours while keeping the gap, then picks every lane at
random. Bots drive at one constant speed, so the gaps between them never shrink.
All randomness comes from the generator passed in (the env's ``np_random``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LinearRing, LineString

from racing.race import LANE_CHANGE_DISTANCE_M, LANE_INNER, LANE_OUTER, RaceConfig
from racing.track import Track

INCH_M = 0.0254
# The DeepRacer package box: 9.5" along the track, 15.25" across, 10.5" high.
BOX_LENGTH_M = 9.5 * INCH_M
BOX_WIDTH_M = 15.25 * INCH_M
BOX_HEIGHT_M = 10.5 * INCH_M
# A bot car's body: a DeepRacer car with its LIDAR shell, metres.
BOT_LENGTH_M = 0.36
BOT_WIDTH_M = 0.19
BOT_HEIGHT_M = 0.2
END_MARGIN_M = 1.0
"""Objects placed by the simulator stop this far before the end of the lap, metres."""
KIND_BOX = "box"
KIND_BOT = "bot"
KIND_RACER = "racer"
"""Another racer's car in a head-to-head race (:mod:`racing.headtohead`): it moves like a bot."""


@dataclass(frozen=True, slots=True)
class RaceObject:
    """A box, a bot car or another racer: centre ``x, y`` (m), ``heading`` (rad,
    counter-clockwise from +x), ``speed`` (m/s; 0 for a box), footprint ``length`` × ``width``
    and ``height`` (m); ``colour`` (RGB) paints a racer in its own colour."""

    x: float
    y: float
    heading: float = 0.0
    speed: float = 0.0
    length: float = BOX_LENGTH_M
    width: float = BOX_WIDTH_M
    height: float = BOX_HEIGHT_M
    kind: str = KIND_BOX
    colour: tuple[int, int, int] | None = None


class Lanes:
    """DeepRacer's two lanes of a track, as offsets (metres left of the centre line)."""

    def __init__(self, track: Track) -> None:
        self.track = track
        line = LinearRing if track.closed else LineString
        centre = shapely.points(track.centre)
        self._half = {
            LANE_INNER: np.asarray(shapely.distance(centre, line(track.inner))) / 2,
            LANE_OUTER: np.asarray(shapely.distance(centre, line(track.outer))) / 2,
        }
        if track.closed:
            inner_left = track.direction == "ccw"
        else:
            mid = len(track.inner) // 2
            inner_left = track.locate(*track.inner[mid]).left
        self._sign = {LANE_INNER: 1.0 if inner_left else -1.0}
        self._sign[LANE_OUTER] = -self._sign[LANE_INNER]
        self._signed = {lane: self._sign[lane] * half for lane, half in self._half.items()}

    def offset(self, s: float, lane: int) -> float:
        """How far left of the centre line lane ``lane`` runs at ``s`` metres, metres."""
        track = self.track
        seg = track.segment_at(s)
        s = s % track.length if track.closed else min(max(s, 0.0), track.length)
        seg_len = track.cumulative[seg + 1] - track.cumulative[seg]
        frac = min(1.0, max(0.0, (s - track.cumulative[seg]) / max(seg_len, 1e-12)))
        half = self._half[lane]
        nxt = (seg + 1) % len(half)
        return self._sign[lane] * float(half[seg] * (1 - frac) + half[nxt] * frac)

    def offsets(self, seg: np.ndarray, frac: np.ndarray, lanes: np.ndarray) -> np.ndarray:
        """:meth:`offset` for many places at once, given as segment indices and fractions along
        them (:meth:`Track.stations`) and lanes (±1)."""
        nxt = (seg + 1) % len(self._signed[LANE_INNER])
        inner = self._signed[LANE_INNER][seg] * (1 - frac) + self._signed[LANE_INNER][nxt] * frac
        outer = self._signed[LANE_OUTER][seg] * (1 - frac) + self._signed[LANE_OUTER][nxt] * frac
        return np.where(lanes == LANE_INNER, inner, outer)

    def point(self, s: float, lane: int) -> tuple[float, float]:
        return self.track.point_at(s, self.offset(s, lane))

    def lane_of(self, offset: float) -> int:
        """The lane on the side of the centre line that ``offset`` (metres left) lies on."""
        return LANE_INNER if offset * self._sign[LANE_INNER] > 0 else LANE_OUTER


def spread(length: float, count: int, gap: float, rng: np.random.Generator | None) -> list[float]:
    """Centre-line distances (m) for ``count`` objects at least ``gap`` metres apart.

    Evenly spaced from ``gap`` to ``length`` - :data:`END_MARGIN_M`; with ``rng`` each one is
    moved at random between its neighbours. Raises ``ValueError`` when they cannot fit.
    """
    start, end = gap, length - END_MARGIN_M
    if end < start or (count > 1 and (end - start) / (count - 1) < gap - 1e-9):
        raise ValueError(
            f"{count} objects {gap:g} m apart do not fit on a {length:.1f} m track; "
            "use fewer objects or a smaller gap"
        )
    dists = list(np.linspace(start, end, count))
    if rng is not None:
        for i in rng.permutation(count):
            lo = start if i == 0 else dists[i - 1] + gap
            hi = end if i == count - 1 else dists[i + 1] - gap
            if lo < hi:
                dists[i] = float(rng.uniform(lo, hi))
    return [float(d) for d in dists]


def choose_lanes(count: int, rng: np.random.Generator | None) -> list[int]:
    """Alternating lanes, inner first; with ``rng`` a random lane each."""
    if rng is None:
        return [LANE_INNER if i % 2 == 0 else LANE_OUTER for i in range(count)]
    return [int(v) for v in rng.choice((LANE_INNER, LANE_OUTER), size=count)]


def place_boxes(
    track: Track, lanes: Lanes, config: RaceConfig, rng: np.random.Generator
) -> tuple[RaceObject, ...]:
    """This episode's boxes, each lying along its lane, in the configured order."""
    if config.object_positions:
        dists = [f * track.length for f, _ in config.object_positions]
        chosen = [lane for _, lane in config.object_positions]
    else:
        random = rng if config.randomize_objects else None
        dists = spread(track.length, config.number_of_objects, config.min_object_gap_m, random)
        chosen = choose_lanes(len(dists), random)
    boxes = []
    for s, lane in zip(dists, chosen, strict=True):
        x, y = lanes.point(s, lane)
        boxes.append(RaceObject(x, y, heading=track.heading_at(s)))
    return tuple(boxes)


@dataclass
class _Bot:
    start_s: float
    lane: int
    target: int
    change_start_m: float = 0.0
    next_change_s: float = math.inf


class BotFleet:
    """Bot cars driving their lanes at ``config.bot_speed`` m/s, changing lane at random.

    :meth:`advance` moves them on by simulated seconds; :meth:`pause` freezes them (DeepRacer
    stops the bots for the penalty time when one runs into the agent from behind).
    """

    def __init__(
        self,
        track: Track,
        lanes: Lanes,
        config: RaceConfig,
        rng: np.random.Generator,
        *,
        keep_clear_m: float = 0.0,
    ) -> None:
        """``keep_clear_m``: no bot starts in the last metres of the lap (a race's grid)."""
        self.track = track
        self.lanes = lanes
        self.config = config
        self.rng = rng
        random = rng if config.randomize_bots else None
        length = track.length - keep_clear_m
        dists = spread(length, config.number_of_bots, config.min_bot_gap_m, random)
        chosen = choose_lanes(len(dists), random)
        self.time_s = 0.0
        self.travelled_m = 0.0
        self._pause_s = 0.0
        self.bots = [_Bot(s, lane, lane) for s, lane in zip(dists, chosen, strict=True)]
        for bot in self.bots:
            self._schedule(bot)
        self.objects = self._poses()

    def _schedule(self, bot: _Bot) -> None:
        if self.config.bot_lane_change:
            wait = self.rng.uniform(self.config.lane_change_min_s, self.config.lane_change_max_s)
            bot.next_change_s = self.time_s + float(wait)

    @property
    def paused(self) -> bool:
        return self._pause_s > 0.0

    def pause(self, seconds: float) -> None:
        """Stop every bot for ``seconds`` of simulated time."""
        self._pause_s += seconds

    def advance(self, seconds: float) -> None:
        """Drive ``seconds`` of simulated time (minus any pause left)."""
        frozen = min(self._pause_s, seconds)
        self._pause_s -= frozen
        run = seconds - frozen
        if run <= 0.0:
            return
        self.time_s += run
        self.travelled_m += run * self.config.bot_speed
        for bot in self.bots:
            if bot.target != bot.lane:
                if self.travelled_m - bot.change_start_m >= LANE_CHANGE_DISTANCE_M:
                    bot.lane = bot.target
                    self._schedule(bot)
            elif self.time_s >= bot.next_change_s:
                bot.target = -bot.lane
                bot.change_start_m = self.travelled_m
        self.objects = self._poses()

    def _poses(self) -> tuple[RaceObject, ...]:
        """Every bot's pose now, computed for all of them at once."""
        s = np.array([bot.start_s for bot in self.bots]) + self.travelled_m
        seg, frac = self.track.stations(s)
        lane = np.array([bot.lane for bot in self.bots])
        target = np.array([bot.target for bot in self.bots])
        here = self.lanes.offsets(seg, frac, lane)
        shift = self.lanes.offsets(seg, frac, target) - here  # 0 unless changing lane
        done = np.clip(
            (self.travelled_m - np.array([bot.change_start_m for bot in self.bots]))
            / LANE_CHANGE_DISTANCE_M,
            0.0,
            1.0,
        )
        eased = done * done * (3.0 - 2.0 * done)  # smoothstep: no kink entering or leaving
        slope = shift * 6.0 * done * (1.0 - done) / LANE_CHANGE_DISTANCE_M  # its derivative
        xs, ys, headings = self.track.points_at(seg, frac, here + shift * eased)
        headings = headings + np.arctan(slope)
        return tuple(
            RaceObject(
                x,
                y,
                heading=h,
                speed=self.config.bot_speed,
                length=BOT_LENGTH_M,
                width=BOT_WIDTH_M,
                height=BOT_HEIGHT_M,
                kind=KIND_BOT,
            )
            for x, y, h in zip(xs.tolist(), ys.tolist(), headings.tolist(), strict=True)
        )
