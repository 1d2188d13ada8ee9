"""One sim-trace file (DeepRacer's 17-19 columns) as numpy arrays, and its summary.

Units: positions metres, ``speed`` m/s (the commanded throttle), ``steer`` degrees, ``tstamp``
seconds of simulated time, ``progress`` percent. An :class:`IterationSummary` holds everything
the charts need from one file: a row per episode, sums on a grid over the track (for the
heatmaps), action counts overall and per track section. Summaries add up into a run's
:class:`~training.analysis.summary.RunSummary`; a single episode is drawn from its file
(:func:`episode_steps`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

from training.analysis.actions import ActionBins

COLUMNS = ("episode", "steps", "x", "y", "yaw", "steer", "speed", "action", "reward",
           "progress", "closest_waypoint", "tstamp")  # fmt: skip
"""The columns kept, in this order."""
_CSV_INDEX = (0, 1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 14)
"""Where they sit in DeepRacer's sim-trace (``episode,steps,X,Y,yaw,steer,throttle,action,
reward,done,all_wheels_on_track,progress,closest_waypoint,track_len,tstamp,...``)."""
_ACTION = 7
"""The ``action`` column: an index, or ``[steer speed]`` text in a continuous space."""
SECTIONS = 10
"""Action usage per track section: the lap cut into this many equal runs of waypoints."""


class TraceError(ValueError):
    """A file that is not a sim-trace."""


@dataclass(frozen=True)
class Grid:
    """Square cells of ``cell`` metres over ``(x0, y0)``-``(x0 + nx*cell, y0 + ny*cell)``."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int

    @classmethod
    def around(cls, bounds: tuple[float, float, float, float], cells: int = 120) -> Grid:
        """A grid over a track's ``(xmin, ymin, xmax, ymax)`` plus a 0.5 m margin, at most
        ``cells`` cells along its longer side."""
        xmin, ymin, xmax, ymax = (bounds[0] - 0.5, bounds[1] - 0.5, bounds[2] + 0.5,
                                  bounds[3] + 0.5)  # fmt: skip
        cell = max(xmax - xmin, ymax - ymin) / cells
        return cls(xmin, ymin, cell, int(np.ceil((xmax - xmin) / cell)),
                   int(np.ceil((ymax - ymin) / cell)))  # fmt: skip

    def index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat cell index of each point (points outside are clipped to the border cells)."""
        ix = np.clip(((x - self.x0) / self.cell).astype(np.int64), 0, self.nx - 1)
        iy = np.clip(((y - self.y0) / self.cell).astype(np.int64), 0, self.ny - 1)
        return iy * self.nx + ix


@dataclass
class Steps:
    """The kept columns of a sim-trace, one array each (``action`` -1 for continuous)."""

    columns: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __len__(self) -> int:
        return len(self.columns["episode"])


def parse_simtrace(data: bytes) -> Steps:
    """A sim-trace CSV (with its header row) as arrays; raises :class:`TraceError`.

    Parsed by numpy's C reader on the numeric columns only: a continuous space's action
    column (``[steer speed]``, text) is skipped and read as -1, without a per-value
    converter (which made a 200,000-step run take seconds)."""
    text = data.decode("utf-8", "replace")
    header, _, body = text.partition("\n")
    names = header.strip().split(",")
    if names[:2] != ["episode", "steps"] or len(names) < 15:
        raise TraceError("not a sim-trace: the header must start with episode,steps")
    if not body.strip():
        return Steps({name: np.zeros(0) for name in COLUMNS})
    first = body[: body.find("\n")] if "\n" in body else body
    continuous = "[" in first
    usecols = tuple(c for c in _CSV_INDEX if not (continuous and c == _ACTION))
    try:
        table = np.loadtxt(io.StringIO(body), delimiter=",", usecols=usecols, ndmin=2,
                           dtype=np.float64)  # fmt: skip
    except ValueError as exc:
        raise TraceError(f"not a sim-trace: {exc}") from None
    columns = {}
    for name, column in zip(COLUMNS, _CSV_INDEX, strict=True):
        if column in usecols:
            columns[name] = table[:, usecols.index(column)]
        else:
            columns[name] = np.full(len(table), -1.0)
    return Steps(columns)


@dataclass
class IterationSummary:
    """What the charts need from one iteration file (see the module's docstring).

    ``episodes``: per episode ``episode, steps, time_s, progress, reward, speed, completed,
    start_waypoint``. ``grid_*``: per grid cell, the number of steps and the sums of reward
    and speed. ``grid_actions`` (cells x bins) and ``section_actions`` (sections x bins)
    count the steps per action bin (:class:`~training.analysis.actions.ActionBins`);
    ``actions`` is their total per bin.
    """

    iteration: int
    episodes: dict[str, np.ndarray]
    grid_count: np.ndarray
    grid_reward: np.ndarray
    grid_speed: np.ndarray
    grid_actions: np.ndarray
    section_actions: np.ndarray
    actions: np.ndarray

    @property
    def num_steps(self) -> int:
        return int(self.grid_count.sum())


def _episode_rows(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """One row per episode of steps sorted by (episode, step)."""
    episode = cols["episode"].astype(np.int64)
    n = len(episode)
    if not n:
        return {"episode": np.zeros(0, np.int64), "steps": np.zeros(0, np.int64),
                "time_s": np.zeros(0), "progress": np.zeros(0), "reward": np.zeros(0),
                "speed": np.zeros(0), "completed": np.zeros(0, bool),
                "start_waypoint": np.zeros(0, np.int64)}  # fmt: skip
    starts = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]])
    ends = np.r_[starts[1:], n] - 1
    count = ends - starts + 1
    progress = np.maximum.reduceat(cols["progress"], starts)
    return {
        "episode": episode[starts],
        "steps": count.astype(np.int64),
        "time_s": cols["tstamp"][ends] - cols["tstamp"][starts],
        "progress": progress,
        "reward": np.add.reduceat(cols["reward"], starts),
        "speed": np.add.reduceat(cols["speed"], starts) / count,
        "completed": progress >= 100.0 - 1e-6,
        "start_waypoint": cols["closest_waypoint"][starts].astype(np.int64),
    }


def summarize(
    steps: Steps, *, iteration: int, grid: Grid, bins: ActionBins, num_waypoints: int
) -> IterationSummary:
    """Sum up one iteration file, its actions counted in ``bins``."""
    order = np.lexsort((steps["steps"], steps["episode"]))
    cols = {name: steps[name][order] for name in COLUMNS}
    cells = grid.nx * grid.ny
    index = grid.index(cols["x"], cols["y"])
    actions = bins.index(cols["action"], cols["steer"], cols["speed"])
    width = max(1, len(bins))
    valid = actions >= 0
    section = np.clip(cols["closest_waypoint"].astype(np.int64) * SECTIONS
                      // max(1, num_waypoints), 0, SECTIONS - 1)  # fmt: skip
    return IterationSummary(
        iteration=iteration,
        episodes=_episode_rows(cols),
        grid_count=np.bincount(index, minlength=cells).astype(np.float64),
        grid_reward=np.bincount(index, weights=cols["reward"], minlength=cells),
        grid_speed=np.bincount(index, weights=cols["speed"], minlength=cells),
        grid_actions=np.bincount(index[valid] * width + actions[valid],
                                 minlength=cells * width).reshape(cells, width),
        section_actions=np.bincount(section[valid] * width + actions[valid],
                                    minlength=SECTIONS * width).reshape(SECTIONS, width),
        actions=np.bincount(actions[valid], minlength=width),
    )  # fmt: skip


EPISODE_COLUMNS = ("steps", "x", "y", "speed", "reward", "action", "progress")
"""The columns of one episode's path (:func:`episode_steps`)."""


def episode_steps(steps: Steps, episode: int) -> dict[str, np.ndarray]:
    """The steps of one episode of a file, in step order (empty arrays if it is not there)."""
    mask = steps["episode"] == episode
    order = np.argsort(steps["steps"][mask], kind="stable")
    return {name: steps[name][mask][order] for name in EPISODE_COLUMNS}
