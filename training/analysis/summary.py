"""A whole run summed up in one small object, so a chart never parses sim-traces.

A :class:`RunSummary` holds what every chart of the analysis page needs, whatever the number
of logged steps: the per-iteration action counts, one row per episode (with its iteration),
and the track grid's and track sections' totals over the run (steps, reward and speed sums,
steps per action bin). Iteration files are written once and never rewritten, so the summary
records which iterations it covers and folds in only the ones it lacks
(:meth:`RunSummary.merged`); a summary that covers an iteration the logs no longer have, or
was made on another grid or with other action bins, is not reused.

Stored as a compressed ``.npz`` of plain arrays (:meth:`RunSummary.to_bytes`), read back
without unpickling (``allow_pickle=False``): a 200,000-step run's summary is tens of
kilobytes, read and turned into any chart's data in milliseconds.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from training.analysis.actions import ActionBins
from training.analysis.trace import SECTIONS, Grid, IterationSummary

SUMMARY_VERSION = 1
"""Bumped when the stored layout changes: a summary of another version is rebuilt."""
EPISODE_FIELDS = {"iteration": np.int64, "episode": np.int64, "steps": np.int64,
                  "time_s": np.float64, "progress": np.float64, "reward": np.float64,
                  "speed": np.float64, "completed": np.bool_,
                  "start_waypoint": np.int64}  # fmt: skip
"""The columns of :attr:`RunSummary.episodes` and their types."""


class SummaryError(ValueError):
    """Stored bytes that are not a summary this code can read."""


@dataclass(frozen=True)
class RunSummary:
    """A run's logs summed up (see the module's docstring). Immutable: :meth:`merged` makes
    a new one, so a summary cached in a process can be read by several threads.

    ``iterations``: the covered iteration numbers (0-based, as the files are named), sorted;
    ``iteration_actions``: steps per action bin, a row per covered iteration; ``episodes``:
    the :data:`EPISODE_FIELDS` columns, sorted by iteration and episode; ``grid_*`` and
    ``section_actions``: totals over the run (as in
    :class:`~training.analysis.trace.IterationSummary`).
    """

    grid: Grid
    bins: ActionBins
    num_waypoints: int
    iterations: np.ndarray
    iteration_actions: np.ndarray
    episodes: dict[str, np.ndarray]
    grid_count: np.ndarray
    grid_reward: np.ndarray
    grid_speed: np.ndarray
    grid_actions: np.ndarray
    section_actions: np.ndarray

    @classmethod
    def empty(cls, grid: Grid, bins: ActionBins, num_waypoints: int) -> RunSummary:
        """A summary of no iterations yet."""
        cells, width = grid.nx * grid.ny, max(1, len(bins))
        episodes = {name: np.zeros(0, dtype) for name, dtype in EPISODE_FIELDS.items()}
        return cls(
            grid=grid, bins=bins, num_waypoints=num_waypoints,
            iterations=np.zeros(0, np.int64), iteration_actions=np.zeros((0, width), np.int64),
            episodes=episodes, grid_count=np.zeros(cells), grid_reward=np.zeros(cells),
            grid_speed=np.zeros(cells), grid_actions=np.zeros((cells, width), np.int64),
            section_actions=np.zeros((SECTIONS, width), np.int64),
        )  # fmt: skip

    def fits(self, grid: Grid, bins: ActionBins, num_waypoints: int) -> bool:
        """Whether the summary was made on this grid, with these bins and waypoints."""
        return (self.grid, self.bins.key(), self.num_waypoints) == (
            grid, bins.key(), num_waypoints)  # fmt: skip

    @property
    def covered(self) -> set[int]:
        return {int(i) for i in self.iterations}

    @property
    def num_steps(self) -> int:
        return int(self.grid_count.sum())

    def merged(self, parts: Iterable[IterationSummary]) -> RunSummary:
        """This summary with the iterations of ``parts`` it does not cover yet folded in
        (an iteration it covers already is skipped: files are never rewritten)."""
        seen, new = self.covered, []
        for part in parts:
            if int(part.iteration) not in seen:
                seen.add(int(part.iteration))
                new.append(part)
        if not new:
            return self
        width = self.iteration_actions.shape[1]
        iterations = np.r_[self.iterations, [p.iteration for p in new]].astype(np.int64)
        actions = np.vstack([self.iteration_actions, *[p.actions.reshape(1, width) for p in new]])
        order = np.argsort(iterations, kind="stable")
        episodes = {
            name: np.concatenate(
                [self.episodes[name], *[_episode_column(p, name) for p in new]]
            ).astype(dtype)
            for name, dtype in EPISODE_FIELDS.items()
        }
        by = np.lexsort((episodes["episode"], episodes["iteration"]))
        return RunSummary(
            grid=self.grid, bins=self.bins, num_waypoints=self.num_waypoints,
            iterations=iterations[order], iteration_actions=actions[order],
            episodes={name: column[by] for name, column in episodes.items()},
            grid_count=self.grid_count + sum(p.grid_count for p in new),
            grid_reward=self.grid_reward + sum(p.grid_reward for p in new),
            grid_speed=self.grid_speed + sum(p.grid_speed for p in new),
            grid_actions=self.grid_actions + sum(p.grid_actions for p in new),
            section_actions=self.section_actions + sum(p.section_actions for p in new),
        )  # fmt: skip

    # ------------------------------------------------------------------ stored form
    def to_bytes(self) -> bytes:
        """The summary as a compressed ``.npz`` (plain arrays and a JSON header)."""
        header = {"version": SUMMARY_VERSION, "grid": [self.grid.x0, self.grid.y0,
                  self.grid.cell, self.grid.nx, self.grid.ny], "bins": self.bins.key(),
                  "num_waypoints": self.num_waypoints}  # fmt: skip
        arrays = {f"episodes_{name}": column for name, column in self.episodes.items()}
        out = io.BytesIO()
        np.savez_compressed(
            out, header=np.frombuffer(json.dumps(header).encode(), np.uint8),
            iterations=self.iterations, iteration_actions=self.iteration_actions,
            grid_count=self.grid_count, grid_reward=self.grid_reward,
            grid_speed=self.grid_speed, grid_actions=_compact(self.grid_actions),
            section_actions=self.section_actions, **arrays,
        )  # fmt: skip
        return out.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes, bins: ActionBins) -> RunSummary:
        """A stored summary made with ``bins``; raises :class:`SummaryError` for bytes that
        are not one, of another version, or made with other bins."""
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
            header = json.loads(arrays.pop("header").tobytes())
            if header.get("version") != SUMMARY_VERSION:
                raise SummaryError(f"summary version {header.get('version')!r}")
            if header.get("bins") != bins.key():
                raise SummaryError("the summary counts other actions")
            x0, y0, cell, nx, ny = header["grid"]
            summary = cls(
                grid=Grid(float(x0), float(y0), float(cell), int(nx), int(ny)), bins=bins,
                num_waypoints=int(header["num_waypoints"]),
                iterations=arrays["iterations"].astype(np.int64),
                iteration_actions=arrays["iteration_actions"].astype(np.int64),
                episodes={name: arrays[f"episodes_{name}"].astype(dtype)
                          for name, dtype in EPISODE_FIELDS.items()},
                grid_count=arrays["grid_count"], grid_reward=arrays["grid_reward"],
                grid_speed=arrays["grid_speed"],
                grid_actions=arrays["grid_actions"].astype(np.int64),
                section_actions=arrays["section_actions"].astype(np.int64),
            )  # fmt: skip
        except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
            raise SummaryError(f"not an analysis summary: {exc}") from None
        summary._check()
        return summary

    def _check(self) -> None:
        """Shapes that agree with each other (a damaged object is refused, not charted)."""
        cells, width = self.grid.nx * self.grid.ny, max(1, len(self.bins))
        lengths = {len(column) for column in self.episodes.values()}
        if (
            self.grid_count.shape != (cells,) or self.grid_reward.shape != (cells,)
            or self.grid_speed.shape != (cells,) or self.grid_actions.shape != (cells, width)
            or self.section_actions.shape != (SECTIONS, width)
            or self.iteration_actions.shape != (len(self.iterations), width)
            or len(lengths) != 1
        ):  # fmt: skip
            raise SummaryError("not an analysis summary: its arrays do not fit together")


def _episode_column(part: IterationSummary, name: str) -> np.ndarray:
    if name == "iteration":
        return np.full(len(part.episodes["episode"]), part.iteration, np.int64)
    return part.episodes[name]


def _compact(counts: np.ndarray) -> np.ndarray:
    """Step counts in the smallest integer type that holds them (the object stays small)."""
    top = int(counts.max()) if counts.size else 0
    return counts.astype(np.uint16 if top < 2**16 else np.uint32 if top < 2**32 else np.int64)
