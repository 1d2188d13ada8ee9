"""Running a head-to-head race of racers' models (:mod:`racing.headtohead`) and reporting it:
per car its position, laps, lap times, total time, penalties and progress; the broadcast MP4;
each car's sim-trace in DeepRacer's evaluation format (one episode per lap), which
deepracer-utils reads as it reads an evaluation's.

No user code runs here: the cars are driven by their policies only, and like an evaluation a
race refuses to run in a process that ever loaded a reward function
(:mod:`training.sandbox.taint`). A car that cannot race (its checkpoint is missing or does not
load) or whose policy fails mid-race is out with the reason; the race goes on without it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from racing.broadcast import BroadcastView
from racing.conditions import Conditions
from racing.headtohead import CarState, HeadToHeadRace, RaceCar, Racer, grid_order
from racing.race import RaceConfig
from racing.rules import RaceRules, Status
from racing.track import Track
from training.rl.evaluation import LapTrace, VideoWriter
from training.sandbox.taint import refuse_if_tainted

log = logging.getLogger(__name__)
MIN_LAPS, MAX_LAPS = 1, 10
LAP_TIME_ALLOWANCE_S = 90.0
"""The default time limit allows this many seconds of race clock per lap."""
Policy = Callable[[object], object]


class RaceError(ValueError):
    """Race settings outside what a race allows."""


@dataclass(frozen=True)
class RaceSettings:
    """``laps`` 1-10; penalties in seconds (DeepRacer's head-to-head: 5 s); ``time_limit_s``
    of race clock (default :data:`LAP_TIME_ALLOWANCE_S` a lap); ``round`` rotates the grid."""

    laps: int = 3
    off_track_penalty_s: float = 5.0
    crash_penalty_s: float = 5.0
    resets: int = 10_000
    time_limit_s: float | None = None
    seed: int = 0
    round: int = 0
    record_video: bool = True

    def __post_init__(self) -> None:
        if not MIN_LAPS <= self.laps <= MAX_LAPS:
            raise RaceError(f"a race runs {MIN_LAPS} to {MAX_LAPS} laps, not {self.laps}")
        for name in ("off_track_penalty_s", "crash_penalty_s"):
            if not 0 <= getattr(self, name) <= 60:
                raise RaceError(f"{name.replace('_', ' ')} must be 0-60 seconds")
        if self.time_limit_s is not None and not 10 <= self.time_limit_s <= 3600:
            raise RaceError("the time limit must be 10-3600 seconds")
        if self.resets < 0 or self.round < 0:
            raise RaceError("resets and round cannot be negative")

    @property
    def limit_s(self) -> float:
        return self.time_limit_s or self.laps * LAP_TIME_ALLOWANCE_S

    def rules(self) -> RaceRules:
        return RaceRules(
            laps=self.laps,
            resets=self.resets,
            off_track_penalty_s=self.off_track_penalty_s,
            crash_penalty_s=self.crash_penalty_s,
            time_limit_s=self.limit_s,
        )


@dataclass
class RaceEntry:
    """One car: who it is (``key``: the model's id), its racer settings, and its policy, or
    ``unavailable`` saying why it cannot race."""

    key: int | str
    name: str
    racer: Racer = field(default_factory=Racer)
    policy: Policy | None = None
    unavailable: str = ""
    metadata: dict = field(default_factory=dict)
    """Its ``model_metadata.json``, written beside its sim-trace."""


@dataclass
class CarReport:
    """One car's race, as the results table and the JSON show it."""

    key: int | str
    name: str
    position: int
    grid: int
    status: str
    reason: str
    finished: bool
    laps_done: int
    lap_times_s: list[float]
    total_time_s: float
    progress: float
    off_track: int
    crashes: int
    resets: int
    rows: list[list] = field(default_factory=list, repr=False)

    def to_json(self) -> dict:
        return {
            "model": self.key,
            "name": self.name,
            "position": self.position,
            "grid": self.grid,
            "status": self.status,
            "reason": self.reason,
            "finished": self.finished,
            "laps": self.laps_done,
            "lap_times_s": self.lap_times_s,
            "total_time_s": self.total_time_s,
            "progress": self.progress,
            "off_track": self.off_track,
            "crashes": self.crashes,
            "resets": self.resets,
        }


@dataclass
class RaceReport:
    cars: list[CarReport]
    laps: int
    steps: int
    race_time_s: float
    video_mp4: bytes | None = None
    stopped: bool = False
    wall_s: float = 0.0

    @property
    def winner(self) -> CarReport | None:
        """The first to finish; at the time limit the one furthest on (none if nobody moved)."""
        first = self.cars[0] if self.cars else None
        if first is None or first.status == CarState.OUT.value or first.progress <= 0.0:
            return None
        return first

    def to_json(self) -> dict:
        """What the command prints and the job keeps: nothing that depends on wall time."""
        winner = self.winner
        return {
            "winner": winner.key if winner else None,
            "cars": [car.to_json() for car in self.cars],
            "laps": self.laps,
            "steps": self.steps,
            "race_time_s": round(self.race_time_s, 3),
            "stopped": self.stopped,
        }


def run_race(
    entries: Sequence[RaceEntry],
    track: Track,
    settings: RaceSettings,
    *,
    race: RaceConfig | None = None,
    title: str = "",
    should_stop: Callable[[], bool] | None = None,
    on_frame: Callable[[object, dict], None] | None = None,
    conditions: Conditions | None = None,
) -> RaceReport:
    """Race ``entries`` (2-4) on ``track`` (a loop, in its driving direction) with ``race``'s
    bots, and report. ``on_frame(rgb, header)`` gets each live broadcast frame as it is drawn
    with its header (the step's timing, shot and layout: :meth:`BroadcastView.header`); the
    MP4 gets the same frame with that timing burnt in; ``should_stop`` is polled every step.
    ``conditions``: the outside world every car's camera sees (a league event's; None: clean)."""
    refuse_if_tainted("A race")  # the judge never shares a process with user code
    started = time.monotonic()
    grid = grid_order(len(entries), settings.round)
    contest = HeadToHeadRace(
        track,
        [entry.racer for entry in entries],
        rules=settings.rules(),
        race=race,
        seed=settings.seed,
        grid=grid,
        conditions=conditions,
    )
    drawing = settings.record_video or on_frame is not None
    view = BroadcastView(contest, title=title) if drawing else None
    video = VideoWriter(view.width, view.height) if settings.record_video and view else None
    traces = [LapTrace() for _ in entries]
    stopped = False
    try:
        for entry in entries:
            if entry.unavailable or entry.policy is None:
                contest.retire(entries.index(entry), entry.unavailable or "no policy")
        observations = contest.reset()
        while not contest.over:
            actions = [_act(contest, i, entry, obs) for i, (entry, obs)
                       in enumerate(zip(entries, observations, strict=True))]  # fmt: skip
            for i, outcome in enumerate(contest.step(actions)):
                if outcome is not None:
                    traces[i].add(outcome.trace, finished=outcome.lap_finished, done=outcome.done)
            observations = contest.observations()
            if view is not None:  # one timing and one picture a step: the MP4 and live
                frame = view.render(observations)
                if video is not None:
                    video.add_frame(view.replay_frame(frame))
                if on_frame is not None:
                    on_frame(frame, view.header())
            if should_stop is not None and should_stop():
                stopped = True
                break
        cars = [_car_report(contest, car, entries[car.index], traces[car.index], position)
                for position, car in enumerate(contest.standings(), start=1)]  # fmt: skip
    finally:
        contest.close()
    return RaceReport(
        cars=cars,
        laps=settings.laps,
        steps=contest.steps,
        race_time_s=contest.clock_s,
        video_mp4=video.finish() if video else None,
        stopped=stopped,
        wall_s=time.monotonic() - started,
    )


def _act(contest: HeadToHeadRace, index: int, entry: RaceEntry, obs: object) -> object | None:
    """The entry's action, or ``None`` when it does not act; a failing policy retires it."""
    if obs is None or entry.policy is None:
        return None
    try:
        return entry.policy(obs)
    except Exception as exc:  # noqa: BLE001 - a broken model is out; the race goes on
        log.warning("race: the policy of %s failed", entry.name, exc_info=True)
        contest.retire(index, f"its policy failed: {type(exc).__name__}: {exc}"[:200])
        return None


def _car_report(
    contest: HeadToHeadRace, car: RaceCar, entry: RaceEntry, trace: LapTrace, position: int
) -> CarReport:
    laps = car.lap_records()
    done = [lap for lap in laps if lap.status is Status.LAP_COMPLETE]
    total = car.finish_time_s if car.finish_time_s is not None else car.tracker.sim_time
    race_m = contest.rules.laps * contest.track.length
    return CarReport(
        key=entry.key,
        name=entry.name,
        position=position,
        grid=car.grid_slot + 1,
        status=car.state.value,
        reason=car.reason,
        finished=car.state is CarState.FINISHED,
        laps_done=len(done),
        lap_times_s=[round(lap.time_s, 3) for lap in done],
        total_time_s=round(total, 3),
        progress=round(100.0 * car.distance_m(contest.track.length) / race_m, 2),
        off_track=sum(lap.off_tracks for lap in laps),
        crashes=sum(lap.crashes for lap in laps),
        resets=sum(lap.resets for lap in laps),
        rows=trace.rows,
    )
