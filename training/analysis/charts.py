"""Chart data from iteration summaries: small JSON-able tables (column name -> list), each
downloadable as CSV (:func:`to_csv`). Units as in :mod:`training.analysis.trace`; times in
seconds, progress and rates in percent."""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np

from training.analysis.trace import SECTIONS, Grid, IterationSummary, Steps, episode_steps

Table = dict[str, list]
HEATMAPS = ("reward", "speed", "action")


def _r(values: np.ndarray, digits: int = 3) -> list:
    """A float array as a list, rounded, NaN as None (JSON null)."""
    rounded = np.round(np.asarray(values, dtype=np.float64), digits)
    return [None if not np.isfinite(v) else float(v) for v in rounded]


def _episodes(summaries: Sequence[IterationSummary]) -> dict[str, np.ndarray]:
    """Every episode of the run, with its iteration (0-based, as the file names)."""
    if not summaries:
        return {"iteration": np.zeros(0, np.int64)}
    parts = [s.episodes for s in summaries]
    out = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    out["iteration"] = np.concatenate(
        [np.full(len(s.episodes["episode"]), s.iteration, np.int64) for s in summaries]
    )
    return out


def progress(summaries: Sequence[IterationSummary], evaluation: dict[int, float]) -> Table:
    """Per iteration: episodes, mean reward and progress, completion rate, mean and standard
    deviation of the completed laps' times, and the evaluation's mean progress
    (``evaluation``: iteration -> percent) where there was one."""
    table: Table = {k: [] for k in ("iteration", "episodes", "reward", "progress",
                                    "completion_rate", "lap_time", "lap_time_std",
                                    "eval_progress")}  # fmt: skip
    for s in summaries:
        e = s.episodes
        done = e["time_s"][e["completed"]]
        table["iteration"].append(s.iteration)
        table["episodes"].append(len(e["episode"]))
        table["reward"] += _r([e["reward"].mean() if len(e["reward"]) else np.nan])
        table["progress"] += _r([e["progress"].mean() if len(e["progress"]) else np.nan], 2)
        table["completion_rate"] += _r([100.0 * e["completed"].mean() if len(e["completed"])
                                        else np.nan], 2)  # fmt: skip
        table["lap_time"] += _r([done.mean() if len(done) else np.nan])
        table["lap_time_std"] += _r([done.std() if len(done) > 1 else np.nan])
        table["eval_progress"] += _r([evaluation.get(s.iteration, np.nan)], 2)
    return table


def heatmap(summaries: Sequence[IterationSummary], grid: Grid, kind: str) -> dict:
    """Cells of the track grid: mean reward or speed per step, or the most chosen action.
    ``values`` is row-major (``ny`` rows of ``nx`` cells from ``y0``), null where no car went."""
    if kind not in HEATMAPS:
        raise ValueError(f"heatmap is one of {HEATMAPS}")
    cells = grid.nx * grid.ny
    count = sum((s.grid_count for s in summaries), np.zeros(cells))
    with np.errstate(invalid="ignore", divide="ignore"):
        if kind == "action":
            actions = sum((s.grid_actions for s in summaries[1:]), summaries[0].grid_actions) \
                if summaries else np.zeros((cells, 1))  # fmt: skip
            values = np.where(actions.sum(axis=1) > 0, actions.argmax(axis=1), np.nan)
        else:
            total = sum((getattr(s, f"grid_{kind}") for s in summaries), np.zeros(cells))
            values = np.where(count > 0, total / count, np.nan)
    return {"kind": kind, "x0": grid.x0, "y0": grid.y0, "cell": grid.cell, "nx": grid.nx,
            "ny": grid.ny, "values": _r(values), "steps": int(count.sum())}  # fmt: skip


def episodes_table(summaries: Sequence[IterationSummary]) -> Table:
    """Every episode: iteration, episode, steps, time (s), progress (%), reward, mean speed."""
    e = _episodes(summaries)
    if not len(e["iteration"]):
        return {k: [] for k in ("iteration", "episode", "steps", "time_s", "progress",
                                "reward", "speed", "completed")}  # fmt: skip
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


def fastest_laps(summaries: Sequence[IterationSummary], count: int = 10) -> Table:
    """The ``count`` fastest completed laps of training, fastest first."""
    table = episodes_table(summaries)
    done = [i for i, c in enumerate(table["completed"]) if c]
    done.sort(key=lambda i: table["time_s"][i])
    return {k: [v[i] for i in done[:count]] for k, v in table.items() if k != "completed"}


def action_usage(summaries: Sequence[IterationSummary], num_actions: int) -> dict:
    """How often each action was chosen: per iteration (percent of its steps) and per track
    section (percent of the section's steps, all iterations)."""
    per_iteration = [_percent(s.actions[:num_actions]) for s in summaries]
    width = max(1, num_actions)
    sections = sum((s.section_actions for s in summaries), np.zeros((SECTIONS, width)))
    return {
        "iterations": [s.iteration for s in summaries],
        "per_iteration": per_iteration,
        "per_section": [_percent(row[:num_actions]) for row in sections],
    }


def _percent(counts: np.ndarray) -> list:
    total = counts.sum()
    return _r(100.0 * counts / total if total else np.zeros(len(counts)), 2)


def episode_path(summary: IterationSummary, episode: int) -> Table:
    """One episode, step by step: position, speed, reward, action and progress."""
    steps = episode_steps(summary, episode)
    return {name: _r(values, 4) for name, values in steps.items() if name != "episode"}


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
