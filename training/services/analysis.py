"""A model's analysis: chart data from its stored logs, and reward replays.

The heavy lifting is Django-free (:mod:`training.analysis`); here the files are found in the
store and each training iteration file is parsed and summed up once per process: a file is
never rewritten once its iteration is logged, so its summary is cached under (model, key)
until the cache's step budget pushes it out (least recently used first). A run of 200,000
steps is parsed once (about a second), after which a chart costs milliseconds.

Replays run the user's reward function in the sandbox on a Celery worker (task
``training.tasks.replay_reward``), never in the web process.
"""

from __future__ import annotations

import functools
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass

from celery.result import AsyncResult

from racing.track import Track
from training import dispatch
from training.analysis import charts
from training.analysis.replay import ReplayError, episode_rows, replay_table, step_params
from training.analysis.trace import Grid, IterationSummary, TraceError, parse_simtrace, summarize
from training.errors import ServiceError
from training.models import EpisodeMetric, EvaluationJob, JobStatus, RacingModel
from training.sandbox import SandboxLimits, check_source, evaluate_reward
from training.services.checks import track_catalog
from training.storage import StoreError
from training.store import get_store, keys_for

CACHE_STEPS = 3_000_000
"""The summaries cached in this process hold at most about this many steps (~100 MB)."""
REPLAY_LIMITS = SandboxLimits(per_call_seconds=1.0, cpu_seconds=120)
"""A replayed reward has DeepRacer's per-step budget, and two minutes for the episode."""
CHARTS = ("progress", "heatmap", "episodes", "fastest", "actions", "evaluations")
_ITERATION_RE = re.compile(r"training-simtrace/(\d+)-iteration\.csv$")
_cache: OrderedDict[tuple[int, str], IterationSummary] = OrderedDict()
_cache_lock = threading.Lock()


@dataclass
class Logs:
    """A model's training logs, summed up: the track grid and one summary per iteration."""

    model: RacingModel
    grid: Grid
    summaries: list[IterationSummary]
    num_actions: int
    action_names: list[str]


def _track(model: RacingModel) -> Track:
    return _load_track(model.track_id, model.direction)


@functools.lru_cache(maxsize=32)
def _load_track(track_id: str, direction: str) -> Track:
    """A track in one direction (cached: building one checks its geometry, ~50 ms)."""
    return track_catalog().load(track_id).in_direction(direction)


def _action_names(model: RacingModel) -> list[str]:
    if not isinstance(model.action_space, list):
        return []
    return [f"{a.get('steering_angle', 0):g}° {a.get('speed', 0):g} m/s"
            for a in model.action_space if isinstance(a, dict)]  # fmt: skip


def _cached(key: tuple[int, str]) -> IterationSummary | None:
    with _cache_lock:
        summary = _cache.get(key)
        if summary is not None:
            _cache.move_to_end(key)
        return summary


def _remember(key: tuple[int, str], summary: IterationSummary) -> None:
    with _cache_lock:
        _cache[key] = summary
        while len(_cache) > 1 and sum(s.num_steps for s in _cache.values()) > CACHE_STEPS:
            _cache.popitem(last=False)


def training_logs(model: RacingModel) -> Logs:
    """The model's training sim-trace files, summed up (from the cache where it can)."""
    track = _track(model)
    grid = Grid.around(track.bounds())
    names = _action_names(model)
    store, prefix = get_store(), keys_for(model.pk).prefix
    try:
        keys = [k for k in store.list(prefix + "training-simtrace/") if _ITERATION_RE.search(k)]
        summaries = []
        for key in sorted(keys, key=lambda k: int(_ITERATION_RE.search(k).group(1))):
            summary = _cached((model.pk, key))
            if summary is None:
                summary = summarize(
                    parse_simtrace(store.get_bytes(key)),
                    iteration=int(_ITERATION_RE.search(key).group(1)), grid=grid,
                    num_actions=len(names), num_waypoints=track.num_waypoints,
                )  # fmt: skip
                _remember((model.pk, key), summary)
            summaries.append(summary)
    except (StoreError, TraceError) as exc:
        raise ServiceError(f"the model's logs could not be read: {exc}") from None
    return Logs(model, grid, summaries, len(names), names)


def _evaluation_progress(model: RacingModel) -> dict[int, float]:
    """Mean progress of the evaluation episodes after each logged iteration (0-based)."""
    out: dict[int, list[int]] = {}
    rows = EpisodeMetric.objects.filter(job__model=model, phase="evaluation").values_list(
        "iteration", "completion_percentage"
    )
    for iteration, completion in rows:
        out.setdefault(iteration - 1, []).append(completion)
    return {k: sum(v) / len(v) for k, v in out.items()}


def _evaluations(model: RacingModel) -> list[EvaluationJob]:
    return list(model.evaluations.filter(status=JobStatus.COMPLETED).order_by("-created_at")[:5])


def evaluation_laps(model: RacingModel) -> list[dict]:
    """The last completed evaluations, each lap step by step (for drawing by speed)."""
    store, keys = get_store(), keys_for(model.pk)
    out = []
    for evaluation in _evaluations(model):
        key = (keys.evaluation_simtrace(evaluation.log_stamp) if evaluation.log_stamp
               else keys.legacy_evaluation_simtrace(evaluation.pk))  # fmt: skip
        try:
            laps = charts.evaluation_laps(parse_simtrace(store.get_bytes(key)))
        except (StoreError, TraceError):
            continue
        out.append({"id": evaluation.pk, "created": evaluation.created_at.isoformat(),
                    "laps": laps})  # fmt: skip
    return out


def analysis_chart(model: RacingModel, chart: str, *, kind: str = "reward") -> dict:
    """One chart's data (``chart`` one of :data:`CHARTS`; ``kind`` picks the heatmap)."""
    if chart not in CHARTS:
        raise ServiceError(f"unknown chart {chart!r}")
    if chart == "evaluations":
        return {"evaluations": evaluation_laps(model)}
    logs = training_logs(model)
    if chart == "progress":
        return charts.progress(logs.summaries, _evaluation_progress(model))
    if chart == "heatmap":
        if kind not in charts.HEATMAPS:
            raise ServiceError(f"heatmap is one of {', '.join(charts.HEATMAPS)}")
        return {**charts.heatmap(logs.summaries, logs.grid, kind), "actions": logs.action_names}
    if chart == "episodes":
        return charts.episodes_table(logs.summaries)
    if chart == "fastest":
        return charts.fastest_laps(logs.summaries)
    return {**charts.action_usage(logs.summaries, logs.num_actions), "actions": logs.action_names}


def analysis_csv(model: RacingModel, chart: str, *, kind: str = "reward") -> str:
    """A chart's data as CSV (tables as they are; the heatmap as x, y, value per cell)."""
    data = analysis_chart(model, chart, kind=kind)
    if chart == "heatmap":
        nx, cell = data["nx"], data["cell"]
        cells = [(i, v) for i, v in enumerate(data["values"]) if v is not None]
        table = {"x": [round(data["x0"] + (i % nx + 0.5) * cell, 3) for i, _ in cells],
                 "y": [round(data["y0"] + (i // nx + 0.5) * cell, 3) for i, _ in cells],
                 kind: [v for _, v in cells]}  # fmt: skip
    elif chart == "actions":
        table = {"iteration": data["iterations"]}
        for a, name in enumerate(data["actions"] or ["action"]):
            table[name] = [row[a] if a < len(row) else None for row in data["per_iteration"]]
    elif chart == "evaluations":
        table = {k: [] for k in ("evaluation", "lap", "time_s")}
        for ev in data["evaluations"]:
            for lap in ev["laps"]:
                table["evaluation"].append(ev["id"])
                table["lap"].append(lap["lap"][0])
                table["time_s"].append(lap["time_s"][0])
    else:
        table = data
    return charts.to_csv(table)


def analysis_episode(model: RacingModel, iteration: int, episode: int) -> dict:
    """One training episode's path, step by step."""
    logs = training_logs(model)
    for summary in logs.summaries:
        if summary.iteration == iteration:
            path = charts.episode_path(summary, episode)
            if path["x"]:
                return path
    raise ServiceError("no such episode in the logs")


def track_outline(model: RacingModel) -> dict:
    """The track to draw, to scale: centre line and borders (metres)."""
    track = _track(model)
    return {"centre": track.centre.round(3).tolist(), "inner": track.inner.round(3).tolist(),
            "outer": track.outer.round(3).tolist(), "closed": track.closed,
            "bounds": track.bounds(), "name": track.name}  # fmt: skip


# ----------------------------------------------------------------------------- reward replay
def replay_start(*, model: RacingModel, iteration: int, episode: int, source: str) -> str:
    """Queue a replay of training episode ``episode`` (of iteration file ``iteration``) with
    reward ``source``; returns the task id. Refuses code that fails the static checks."""
    errors = check_source(source)
    if errors:
        raise ServiceError(errors[0].message, field="reward_function")
    if not get_store().exists(keys_for(model.pk).simtrace(iteration)):
        raise ServiceError("no such iteration in the logs")
    return dispatch.send(dispatch.REPLAY_REWARD, model.pk, iteration, episode, source)


def replay_run(model_id: int, iteration: int, episode: int, source: str) -> dict:
    """The replay itself (a Celery worker runs it): params rebuilt per step, the reward run
    in the sandbox, the new rewards next to the recorded ones."""
    model = RacingModel.objects.get(pk=model_id)
    try:
        rows = episode_rows(get_store().get_bytes(keys_for(model_id).simtrace(iteration)), episode)
        params = step_params(rows, _track(model))
    except (ReplayError, StoreError) as exc:
        return {"model": model_id, "error": str(exc)}
    result = evaluate_reward(source, params, limits=REPLAY_LIMITS)
    errors = [o.error.message for o in result.outcomes if o.error is not None]
    table = replay_table(rows, [o.value for o in result.outcomes])
    return {"model": model.pk, "iteration": iteration, "episode": episode, **table,
            "errors": errors[:3], "output": result.output[-2000:]}  # fmt: skip


def replay_result(*, model: RacingModel, task_id: str) -> dict:
    """``{"state": ...}`` of a replay, with its result once done (only the model's own)."""
    result = AsyncResult(task_id)
    if not result.ready():
        return {"state": "PENDING"}
    value = result.result if result.successful() else None
    if not isinstance(value, dict) or value.get("model") != model.pk:
        return {"state": "FAILED", "error": "the replay failed"}
    return {"state": "DONE", **value}
