"""Sim-trace rows: DeepRacer's per-step log, which the community's log-analysis tools read.

The 19 columns and printf formats of SimApp's current ``StepMetrics`` (spec §8.3). Files are
written with a header row of the column names, as ``training-simtrace/<n>-iteration.csv``.
"""

from __future__ import annotations

import io
import time
from typing import NamedTuple

SIMTRACE_COLUMNS = (
    "episode",
    "steps",
    "X",
    "Y",
    "yaw",
    "steer",
    "throttle",
    "action",
    "reward",
    "done",
    "all_wheels_on_track",
    "progress",
    "closest_waypoint",
    "track_len",
    "tstamp",
    "episode_status",
    "pause_duration",
    "obstacle_crash_counter",
    "wall_clock",
)


class TraceRow(NamedTuple):
    """One step, as SimApp logs it. Two columns need more than the env knows:

    ``wall_clock``: when the step happened, seconds since the epoch (SimApp's ``time.time()``),
    strictly increasing within an episode; ``deepracer-utils`` divides simulated by wall-clock
    time for its real-time factor and takes an iteration's first and last stamps for its
    timing. The env leaves it 0 so that its steps never depend on wall time; whoever records
    the row stamps it then (:meth:`stamped`: the rollout worker as the car steps, the
    evaluation as it drives).

    ``pause_duration``: SimApp's penalty pause still to serve, seconds: the penalty the car
    earned on this step (off track, crashed, reversed or immobilised where the race resets the
    car), 0 on every other step. SimApp then logs ``pause`` rows while the time runs out;
    Racecraft serves the pause within the step (the bots drive on, the clock jumps), so this
    row's ``tstamp`` already includes it and no ``pause`` rows follow.
    """

    episode: int
    steps: int
    x: float
    y: float
    yaw: float
    steer: float
    throttle: float
    action: int | tuple[float, float]
    reward: float
    done: bool
    all_wheels_on_track: bool
    progress: float
    closest_waypoint: int
    track_len: float
    tstamp: float
    episode_status: str
    pause_duration: float
    obstacle_crash_counter: int
    wall_clock: float

    def stamped(self) -> TraceRow:
        """The row with ``wall_clock`` set to now (the env leaves it 0 to stay deterministic)."""
        return self._replace(wall_clock=time.time())

    def format(self) -> str:
        """The row as SimApp writes it (its printf formats, comma-separated); an unstamped
        ``wall_clock`` is written as the time of writing."""
        wall = self.wall_clock if self.wall_clock > 0 else time.time()
        if isinstance(self.action, tuple):
            action = f"[{self.action[0]:.2f} {self.action[1]:.2f}]"
        else:
            action = str(self.action)
        return (
            f"{self.episode:d},{self.steps:d},{self.x:.4f},{self.y:.4f},{self.yaw:.4f},"
            f"{self.steer:.2f},{self.throttle:.2f},{action},{self.reward:.4f},{self.done},"
            f"{self.all_wheels_on_track},{self.progress:.4f},{self.closest_waypoint:d},"
            f"{self.track_len:.2f},{self.tstamp:.3f},{self.episode_status},"
            f"{self.pause_duration:.2f},{self.obstacle_crash_counter:d},{wall:.4f}"
        )


def to_csv(rows: list[TraceRow]) -> str:
    """A sim-trace CSV file: the header row, then one line per step."""
    out = io.StringIO()
    out.write(",".join(SIMTRACE_COLUMNS) + "\n")
    for row in rows:
        out.write(row.format() + "\n")
    return out.getvalue()


SPEED_MULTIPLIER_COLUMN = "speed_multiplier"
"""A race car's trace (:mod:`racing.headtohead`) adds this column after DeepRacer's 19: the
live speed multiplier the car drove each step with. Readers that know only the 19 columns
(deepracer-utils reads by header name, ``training.analysis`` by position) ignore it."""


def with_column(csv: str, name: str, values: list[float]) -> str:
    """``csv`` (a sim-trace: a header row, then one line per step) with a last column ``name``
    holding ``values``, one per step (printf ``%.2f``). ValueError unless there is exactly one
    value per step."""
    lines = csv.rstrip("\n").split("\n")
    if len(lines) - 1 != len(values):
        raise ValueError(f"{len(lines) - 1} steps but {len(values)} values for {name}")
    out = [f"{lines[0]},{name}"]
    out.extend(f"{line},{value:.2f}" for line, value in zip(lines[1:], values, strict=True))
    return "\n".join(out) + "\n"
