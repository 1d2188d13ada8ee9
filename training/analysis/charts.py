"""Chart data from a run's summary: small JSON-able tables (column name -> list), each
downloadable as CSV (:func:`to_csv`). Units as in :mod:`training.analysis.trace`; times in
seconds, progress and rates in percent."""

from __future__ import annotations

import io

import numpy as np

from training.analysis.summary import RunSummary
from training.analysis.trace import Steps, episode_steps

Table = dict[str, list]
HEATMAPS = ("reward", "speed", "action")


def _r(values: np.ndarray, digits: int = 3) -> list:
    """A float array as a list, rounded, NaN as None (JSON null)."""
    rounded = np.round(np.asarray(values, dtype=np.float64), digits)
    out = rounded.tolist()
    for i in np.flatnonzero(~np.isfinite(rounded)):
        out[i] = None
    return out


def progress(summary: RunSummary, evaluation: dict[int, float]) -> Table:
    """Per iteration: episodes, mean reward and progress, completion rate, mean and standard
    deviation of the completed laps' times, and the evaluation's mean progress
    (``evaluation``: iteration -> percent) where there was one."""
    e = summary.episodes
    iterations = summary.iterations
    # Episodes are sorted by iteration: each iteration's rows are one run of the table.
    starts = np.searchsorted(e["iteration"], iterations, side="left")
    ends = np.searchsorted(e["iteration"], iterations, side="right")
    count = (ends - starts).astype(np.float64)
    done = e["completed"].astype(np.float64)
    lap = np.where(e["completed"], e["time_s"], 0.0)

    def per_iteration(values: np.ndarray) -> np.ndarray:
        """The sum of ``values`` over each iteration's episodes."""
        sums = np.r_[0.0, np.cumsum(values)]
        return sums[ends] - sums[starts]

    laps = per_iteration(done)
    with np.errstate(invalid="ignore", divide="ignore"):
        lap_mean = per_iteration(lap) / laps
        lap_var = per_iteration(lap * lap) / laps - lap_mean**2
        return {
            "iteration": iterations.tolist(),
            "episodes": count.astype(np.int64).tolist(),
            "reward": _r(per_iteration(e["reward"]) / count),
            "progress": _r(per_iteration(e["progress"]) / count, 2),
            "completion_rate": _r(100.0 * laps / count, 2),
            "lap_time": _r(lap_mean),
            "lap_time_std": _r(np.where(laps > 1, np.sqrt(np.maximum(lap_var, 0.0)), np.nan)),
            "eval_progress": _r([evaluation.get(int(i), np.nan) for i in iterations], 2),
        }


def heatmap(summary: RunSummary, kind: str) -> dict:
    """Cells of the track grid: mean reward or speed per step, or the most chosen action
    (bin). ``values`` is row-major (``ny`` rows of ``nx`` cells from ``y0``), null where no
    car went (or, for actions, where no step had an action bin)."""
    if kind not in HEATMAPS:
        raise ValueError(f"heatmap is one of {HEATMAPS}")
    grid, count = summary.grid, summary.grid_count
    with np.errstate(invalid="ignore", divide="ignore"):
        if kind == "action":
            actions = summary.grid_actions
            values = np.where(actions.sum(axis=1) > 0, actions.argmax(axis=1), np.nan)
        else:
            total = summary.grid_reward if kind == "reward" else summary.grid_speed
            values = np.where(count > 0, total / count, np.nan)
    return {"kind": kind, "x0": grid.x0, "y0": grid.y0, "cell": grid.cell, "nx": grid.nx,
            "ny": grid.ny, "values": _r(values), "steps": int(count.sum())}  # fmt: skip


def episodes_table(summary: RunSummary) -> Table:
    """Every episode: iteration, episode, steps, time (s), progress (%), reward, mean speed."""
    e = summary.episodes
    return {
        "iteration": e["iteration"].tolist(),
        "episode": e["episode"].tolist(),
        "steps": e["steps"].tolist(),
        "time_s": _r(e["time_s"]),
        "progress": _r(e["progress"], 2),
        "reward": _r(e["reward"]),
        "speed": _r(e["speed"]),
        "completed": e["completed"].tolist(),
    }


def fastest_laps(summary: RunSummary, count: int = 10) -> Table:
    """The ``count`` fastest completed laps of training, fastest first."""
    e = summary.episodes
    done = np.flatnonzero(e["completed"])
    best = done[np.argsort(e["time_s"][done], kind="stable")[:count]]
    return {
        "iteration": e["iteration"][best].tolist(),
        "episode": e["episode"][best].tolist(),
        "steps": e["steps"][best].tolist(),
        "time_s": _r(e["time_s"][best]),
        "progress": _r(e["progress"][best], 2),
        "reward": _r(e["reward"][best]),
        "speed": _r(e["speed"][best]),
    }


def action_usage(summary: RunSummary) -> dict:
    """How often each action (bin) was chosen: per iteration (percent of its steps) and per
    track section (percent of the section's steps, all iterations)."""
    width = len(summary.bins)
    return {
        "iterations": summary.iterations.tolist(),
        "per_iteration": [_percent(row[:width]) for row in summary.iteration_actions],
        "per_section": [_percent(row[:width]) for row in summary.section_actions],
    }


def _percent(counts: np.ndarray) -> list:
    total = counts.sum()
    return _r(100.0 * counts / total if total else np.zeros(len(counts)), 2)


def episode_path(steps: Steps, episode: int) -> Table:
    """One episode of an iteration file, step by step: position, speed, reward, action (or
    action bin) and progress."""
    return {name: _r(values, 4) for name, values in episode_steps(steps, episode).items()}


def evaluation_laps(steps: Steps) -> list[Table]:
    """An evaluation's laps (one episode each), step by step: position, speed, progress, and
    the lap time (s) from its ``prepare`` row to its last."""
    laps = []
    episode = steps["episode"]
    for number in np.unique(episode):
        mask = episode == number
        tstamp = steps["tstamp"][mask]
        laps.append({
            "lap": [int(number) + 1], "time_s": _r([tstamp.max() - tstamp.min()]),
            "x": _r(steps["x"][mask], 4), "y": _r(steps["y"][mask], 4),
            "speed": _r(steps["speed"][mask]), "progress": _r(steps["progress"][mask], 2),
        })  # fmt: skip
    return laps


def to_csv(table: Table) -> str:
    """A table (equal-length columns) as CSV text with a header row."""
    out = io.StringIO()
    names = list(table)
    out.write(",".join(names) + "\n")
    for row in zip(*(table[n] for n in names), strict=True):
        out.write(",".join("" if v is None else str(v) for v in row) + "\n")
    return out.getvalue()
