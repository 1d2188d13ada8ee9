"""Race rules: episode status, laps, lap times, resets and penalties, as DeepRacer judges them.

An episode ends at the first of: the last lap complete (progress reaches 100 % of a lap); off
track (all four wheels off); crashed; reversed (progress falls for 15 steps in a row);
immobilized (the car moves at most 0.3 mm per step for 15 steps in a row); or time up. In
evaluation, a budget of resets turns off-track, crash, reversed and immobilized events into a
penalty (the car is frozen for that many simulated seconds, which count in the lap time) and a
respawn, and the lap goes on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum


class Status(str, Enum):
    """DeepRacer's ``episode_status`` values (the sim-trace column and the metrics labels)."""

    PREPARE = "prepare"
    IN_PROGRESS = "in_progress"
    OFF_TRACK = "off_track"
    CRASHED = "crashed"
    LAP_COMPLETE = "lap_complete"
    REVERSED = "reversed"
    IMMOBILIZED = "immobilized"
    TIME_UP = "time_up"
    PAUSE = "pause"
    PARK = "park"

    @property
    def label(self) -> str:
        return STATUS_LABELS[self]


STATUS_LABELS = {
    Status.PREPARE: "Prepare",
    Status.IN_PROGRESS: "In progress",
    Status.OFF_TRACK: "Off track",
    Status.CRASHED: "Crashed",
    Status.LAP_COMPLETE: "Lap complete",
    Status.REVERSED: "Reversed",
    Status.IMMOBILIZED: "Immobilized",
    Status.TIME_UP: "Time Up",
    Status.PAUSE: "Pause",
    Status.PARK: "Park",
}

FAILURES = (Status.OFF_TRACK, Status.CRASHED, Status.REVERSED, Status.IMMOBILIZED)
REVERSED_STEPS = 15
IMMOBILIZED_STEPS = 15
IMMOBILIZED_DISTANCE_M = 0.0003
MAX_EPISODE_STEPS = 100_000
STALL_GAIN_M = 0.1
EVALUATION_BOT_PAUSE_S = 2.0
"""SimApp's default ``PENALTY_SECONDS`` in evaluation: bots stop this long after hitting the car."""


@dataclass(frozen=True)
class RaceRules:
    """How an episode is judged.

    ``laps``: laps to drive back to back before the episode ends (training uses 1).
    ``resets``: failures forgiven with a penalty and a respawn (training uses 0).
    Penalties are simulated seconds; ``reversed_penalty_s`` defaults to the off-track one.
    ``time_limit_s``: optional limit on simulated time for the whole episode.
    ``lap_time_limit_s``: a lap not finished in this much simulated time ends the episode
    (time up); ``None`` sets it from the track: ``max(180 s, length / 0.4 m/s)``, so a car
    circling on a wide track cannot hold an episode forever.
    ``stall_s``: a car that gains no new ground on its lap (0.1 m past its best) for this many
    simulated seconds is judged immobilized. DeepRacer has no such rule; its narrow tracks do
    not let a car circle for long, but a wide one does, and such episodes teach nothing.
    ``None`` turns it off.
    ``bot_pause_s``: how long the bot cars stop after one runs into the car from behind (the car
    is not at fault; SimApp's ``PENALTY_SECONDS``). ``None`` is SimApp's default: 2 s when
    resets are allowed (evaluation), 0 in training. Running into a bot from behind is a crash
    like hitting a box and costs ``crash_penalty_s``.
    ``mercy_resets``: after this many respawns in a row behind the same box, the car is put
    past it instead (SimApp's optional mercy reset, 3 when enabled there); ``None`` is off.
    """

    laps: int = 1
    resets: int = 0
    off_track_penalty_s: float = 2.0
    crash_penalty_s: float = 5.0
    reversed_penalty_s: float | None = None
    immobilized_penalty_s: float = 0.0
    max_steps: int = MAX_EPISODE_STEPS
    time_limit_s: float | None = None
    lap_time_limit_s: float | None = None
    stall_s: float | None = 10.0
    bot_pause_s: float | None = None
    mercy_resets: int | None = None

    def __post_init__(self) -> None:
        if self.laps < 1:
            raise ValueError("laps must be at least 1")
        if self.resets < 0:
            raise ValueError("resets cannot be negative")
        for name in ("off_track_penalty_s", "crash_penalty_s", "immobilized_penalty_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} cannot be negative")
        if self.bot_pause_s is not None and self.bot_pause_s < 0:
            raise ValueError("bot_pause_s cannot be negative")
        if self.mercy_resets is not None and self.mercy_resets < 1:
            raise ValueError("mercy_resets must be at least 1 (or None for no mercy)")
        if self.max_steps < 1:
            raise ValueError("max_steps must be at least 1")

    def bot_pause(self) -> float:
        """Seconds the bots stop after running into the car from behind (see the class)."""
        if self.bot_pause_s is not None:
            return self.bot_pause_s
        return EVALUATION_BOT_PAUSE_S if self.resets > 0 else 0.0

    def penalty_for(self, status: Status) -> float:
        if status is Status.OFF_TRACK:
            return self.off_track_penalty_s
        if status is Status.CRASHED:
            return self.crash_penalty_s
        if status is Status.REVERSED:
            return (
                self.off_track_penalty_s
                if self.reversed_penalty_s is None
                else self.reversed_penalty_s
            )
        if status is Status.IMMOBILIZED:
            return self.immobilized_penalty_s
        return 0.0


@dataclass
class LapRecord:
    """One lap: its time (penalties included), how it ended and what happened on it."""

    lap: int
    time_s: float
    status: Status
    progress: float
    off_tracks: int = 0
    crashes: int = 0
    reversals: int = 0
    immobilizations: int = 0
    resets: int = 0
    penalty_s: float = 0.0


@dataclass
class Judgement:
    """What the rules made of one step."""

    status: Status
    done: bool
    truncated: bool
    reset: bool
    penalty_s: float
    lap_finished: bool


@dataclass
class RaceTracker:
    """Follows one episode: progress, lap times, failure counters, resets.

    ``track_length`` in metres; ``closed`` says whether distances wrap round the loop.
    Feed it every step with :meth:`update`.
    """

    rules: RaceRules
    track_length: float
    closed: bool = True
    steps: int = 0
    distance: float = 0.0
    """Distance driven along the centre line on the current lap, metres (can be negative)."""
    laps: list[LapRecord] = field(default_factory=list)
    resets_used: int = 0
    sim_time: float = 0.0
    lap_start_time: float = 0.0
    episode_start_time: float = 0.0
    _last_s: float = 0.0
    _falling: int = 0
    _still: int = 0
    _best: float = 0.0
    _best_time: float = 0.0
    _lap: LapRecord | None = None

    @property
    def _lap_limit(self) -> float:
        if self.rules.lap_time_limit_s is not None:
            return self.rules.lap_time_limit_s
        return max(180.0, self.track_length / 0.4)

    def start(self, s: float, sim_time: float = 0.0) -> None:
        self.steps = 0
        self.distance = 0.0
        self.laps = []
        self.resets_used = 0
        self.sim_time = sim_time
        self.lap_start_time = sim_time
        self.episode_start_time = sim_time
        self._last_s = s
        self._falling = 0
        self._still = 0
        self._best = 0.0
        self._best_time = sim_time
        self._lap = LapRecord(lap=1, time_s=0.0, status=Status.IN_PROGRESS, progress=0.0)

    @property
    def progress(self) -> float:
        """Share of the current lap covered since its start point, percent, 0..100."""
        if self.distance >= self.track_length:
            return 100.0  # exactly, as reward functions test for it
        return min(100.0, max(0.0, 100.0 * self.distance / self.track_length))

    @property
    def lap_number(self) -> int:
        return len(self.laps) + 1

    @property
    def current_lap(self) -> LapRecord:
        assert self._lap is not None, "call start() first"
        return self._lap

    def advance(self, s: float) -> float:
        """Account for the car's new centre-line position ``s``; returns the signed delta."""
        delta = s - self._last_s
        if self.closed:
            half = self.track_length / 2
            if delta > half:
                delta -= self.track_length
            elif delta < -half:
                delta += self.track_length
        self._last_s = s
        self.distance += delta
        return delta

    def update(
        self,
        *,
        s: float,
        dt: float,
        moved_m: float,
        wheels_on_track: int,
        crashed: bool = False,
    ) -> Judgement:
        """Judge one step: the car is now at ``s`` metres along the centre line."""
        self.steps += 1
        self.sim_time += dt
        before = self.progress
        self.advance(s)
        after = self.progress
        self._falling = self._falling + 1 if after < before else 0
        self._still = self._still + 1 if moved_m <= IMMOBILIZED_DISTANCE_M else 0

        status = Status.IN_PROGRESS
        if self.distance >= self.track_length:
            return self._finish_lap()
        if crashed:
            status = Status.CRASHED
        elif wheels_on_track == 0:
            status = Status.OFF_TRACK
        elif self._falling >= REVERSED_STEPS:
            status = Status.REVERSED
        elif self._still >= IMMOBILIZED_STEPS or self._stalled():
            status = Status.IMMOBILIZED

        if status in FAILURES:
            self._count(status)
            if self.resets_used < self.rules.resets:
                return self._reset(status)
            return self._end(status, truncated=False)
        if (
            self.steps >= self.rules.max_steps
            or self.sim_time - self.lap_start_time >= self._lap_limit - 1e-9
            or self.rules.time_limit_s is not None
            and self.sim_time - self.episode_start_time >= self.rules.time_limit_s - 1e-9
        ):
            return self._end(Status.TIME_UP, truncated=True)
        return Judgement(status, False, False, False, 0.0, False)

    def _stalled(self) -> bool:
        if self.distance > self._best + STALL_GAIN_M:
            self._best = self.distance
            self._best_time = self.sim_time
            return False
        return self.rules.stall_s is not None and (
            self.sim_time - self._best_time >= self.rules.stall_s - 1e-9
        )

    def _count(self, status: Status) -> None:
        lap = self.current_lap
        if status is Status.OFF_TRACK:
            lap.off_tracks += 1
        elif status is Status.CRASHED:
            lap.crashes += 1
        elif status is Status.REVERSED:
            lap.reversals += 1
        elif status is Status.IMMOBILIZED:
            lap.immobilizations += 1

    def _reset(self, status: Status) -> Judgement:
        penalty = self.rules.penalty_for(status)
        self.resets_used += 1
        self.current_lap.resets += 1
        self.current_lap.penalty_s += penalty
        self.sim_time += penalty
        self._falling = 0
        self._still = 0
        self._best_time = self.sim_time
        return Judgement(status, False, False, True, penalty, False)

    def respawned_at(self, s: float) -> None:
        """The car was put back at ``s`` after a reset: progress continues from there."""
        self._last_s = s

    def _finish_lap(self) -> Judgement:
        lap = self.current_lap
        lap.time_s = self.sim_time - self.lap_start_time
        lap.progress = 100.0
        lap.status = Status.LAP_COMPLETE
        self.laps.append(lap)
        self.distance -= self.track_length
        self.lap_start_time = self.sim_time
        self._best = self.distance
        self._best_time = self.sim_time
        self._lap = LapRecord(
            lap=len(self.laps) + 1, time_s=0.0, status=Status.IN_PROGRESS, progress=0.0
        )
        self._falling = 0
        if len(self.laps) >= self.rules.laps:
            self.distance = self.track_length  # progress stays at 100 for the final report
            return Judgement(Status.LAP_COMPLETE, True, False, False, 0.0, True)
        return Judgement(Status.IN_PROGRESS, False, False, False, 0.0, True)

    def _end(self, status: Status, *, truncated: bool) -> Judgement:
        lap = self.current_lap
        lap.status = status
        lap.time_s = self.sim_time - self.lap_start_time
        lap.progress = self.progress
        return Judgement(status, not truncated, truncated, False, 0.0, False)
