"""One sim-trace file (DeepRacer's 17-19 columns) as numpy arrays, and its summary.

Units: positions metres, ``speed`` m/s (the commanded throttle), ``steer`` degrees, ``tstamp``
seconds of simulated time, ``progress`` percent. An :class:`IterationSummary` holds everything
the charts need from one file: a row per episode, sums on a grid over the track (for the
heatmaps), action counts overall and per track section, and the steps themselves (float32) for
drawing single episodes. Summaries add up: :mod:`training.analysis.charts` combines them.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

COLUMNS = ("episode", "steps", "x", "y", "yaw", "steer", "speed", "action", "reward",
           "progress", "closest_waypoint", "tstamp")  # fmt: skip
"""The columns kept, in this order."""
_CSV_INDEX = (0, 1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 14)
"""Where they sit in DeepRacer's sim-trace (``episode,steps,X,Y,yaw,steer,throttle,action,
reward,done,all_wheels_on_track,progress,closest_waypoint,track_len,tstamp,...``)."""
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
    """A sim-trace CSV (with its header row) as arrays; raises :class:`TraceError`."""
    text = data.decode("utf-8", "replace")
    header, _, body = text.partition("\n")
    names = header.strip().split(",")
    if names[:2] != ["episode", "steps"] or len(names) < 15:
        raise TraceError("not a sim-trace: the header must start with episode,steps")
    if not body.strip():
        return Steps({name: np.zeros(0) for name in COLUMNS})
    continuous = "[" in body[: body.find("\n") if "\n" in body else len(body)]
    converters = {7: lambda s: -1.0} if continuous else None
    try:
        table = np.loadtxt(io.StringIO(body), delimiter=",", usecols=_CSV_INDEX, ndmin=2,
                           converters=converters, dtype=np.float64)  # fmt: skip
    except ValueError as exc:
        raise TraceError(f"not a sim-trace: {exc}") from None
    return Steps({name: table[:, i] for i, name in enumerate(COLUMNS)})


@dataclass
class IterationSummary:
    """What the charts need from one iteration file (see the module's docstring).

    ``episodes``: per episode ``episode, steps, time_s, progress, reward, speed, completed,
    start_waypoint``. ``grid_*``: per grid cell, the number of steps and the sums of reward
    and speed. ``grid_actions`` (cells x actions) and ``section_actions`` (sections x
    actions) count the discrete actions chosen; ``actions`` is their total per action.
    """

    iteration: int
    episodes: dict[str, np.ndarray]
    grid_count: np.ndarray
    grid_reward: np.ndarray
    grid_speed: np.ndarray
    grid_actions: np.ndarray
    section_actions: np.ndarray
    actions: np.ndarray
    steps: dict[str, np.ndarray]

    @property
    def num_steps(self) -> int:
        return int(self.grid_count.sum())


def summarize(
    steps: Steps, *, iteration: int, grid: Grid, num_actions: int, num_waypoints: int
) -> IterationSummary:
    """Sum up one iteration file (``num_actions`` 0 for a continuous action space)."""
    episode = steps["episode"].astype(np.int64)
    n = len(episode)
    order = np.lexsort((steps["steps"], episode))
    cols = {name: steps[name][order] for name in COLUMNS}
    episode = episode[order]
    starts = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]]) if n else np.zeros(0, int)
    ends = np.r_[starts[1:], n] - 1 if n else np.zeros(0, int)
    progress = np.maximum.reduceat(cols["progress"], starts) if n else np.zeros(0)
    episodes = {
        "episode": episode[starts] if n else np.zeros(0, np.int64),
        "steps": (ends - starts + 1).astype(np.int64),
        "time_s": (cols["tstamp"][ends] - cols["tstamp"][starts]) if n else np.zeros(0),
        "progress": progress,
        "reward": np.add.reduceat(cols["reward"], starts) if n else np.zeros(0),
        "speed": (np.add.reduceat(cols["speed"], starts) / (ends - starts + 1)) if n else
        np.zeros(0),
        "completed": progress >= 100.0 - 1e-6,
        "start_waypoint": cols["closest_waypoint"][starts].astype(np.int64) if n else
        np.zeros(0, np.int64),
    }  # fmt: skip
    cells = grid.nx * grid.ny
    index = grid.index(cols["x"], cols["y"])
    actions = cols["action"].astype(np.int64)
    width = max(1, num_actions)
    valid = (actions >= 0) & (actions < num_actions)
    section = np.clip(cols["closest_waypoint"].astype(np.int64) * SECTIONS
                      // max(1, num_waypoints), 0, SECTIONS - 1)  # fmt: skip
    return IterationSummary(
        iteration=iteration,
        episodes=episodes,
        grid_count=np.bincount(index, minlength=cells).astype(np.float64),
        grid_reward=np.bincount(index, weights=cols["reward"], minlength=cells),
        grid_speed=np.bincount(index, weights=cols["speed"], minlength=cells),
        grid_actions=np.bincount(index[valid] * width + actions[valid],
                                 minlength=cells * width).reshape(cells, width),
        section_actions=np.bincount(section[valid] * width + actions[valid],
                                    minlength=SECTIONS * width).reshape(SECTIONS, width),
        actions=np.bincount(actions[valid], minlength=width),
        steps={name: cols[name].astype(np.float32) for name in
               ("episode", "steps", "x", "y", "speed", "reward", "action", "progress")},
    )  # fmt: skip


def episode_steps(summary: IterationSummary, episode: int) -> dict[str, np.ndarray]:
    """The steps of one episode of the file (empty arrays if it is not there)."""
    mask = summary.steps["episode"] == episode
    return {name: values[mask] for name, values in summary.steps.items()}
