"""A model's analysis: chart data from its stored logs, and reward replays.

The heavy lifting is Django-free (:mod:`training.analysis`). A model's run is summed up in
one small object in its folder (``analysis/summary.npz``, a
:class:`~training.analysis.summary.RunSummary`): the training worker folds each iteration in
as it is logged (:func:`analysis_summary_update`), so a chart reads that object and the
folder's listing, never the run's sim-traces, however many steps were logged. A model without
one (imported, or trained before summaries) gets it made on its first view, from its files,
and saved. Each process also keeps the last summaries it read; a single episode is drawn from
its one iteration file.

Replays run the user's reward function in the sandbox on a Celery worker (task
``training.tasks.replay_reward``), never in the web process.
"""

from __future__ import annotations

import functools
import logging
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass

from celery.result import AsyncResult

from racing.track import Track
from training import dispatch
from training.analysis import charts
from training.analysis.actions import ActionBins
from training.analysis.replay import ReplayError, episode_rows, replay_table, step_params
from training.analysis.summary import RunSummary, SummaryError
from training.analysis.trace import Grid, Steps, TraceError, parse_simtrace, summarize
from training.errors import ServiceError
from training.models import EpisodeMetric, EvaluationJob, JobStatus, RacingModel
from training.sandbox import SandboxLimits, check_source, evaluate_reward
from training.services.checks import track_catalog
from training.services.trackfiles import tracks_sync_for
from training.storage import ObjectNotFound, ObjectStore, StoreError
from training.store import get_store, keys_for

SUMMARY_NAME = "analysis/summary.npz"
"""The run's summary, inside the model's folder (not part of the logs or model downloads)."""
CACHED_SUMMARIES = 32
"""Summaries kept in this process (least recently used out; tens of kilobytes to a few MB)."""
CACHED_FILES = 4
"""Parsed iteration files kept in this process, for drawing episodes (the best laps' three)."""
REPLAY_LIMITS = SandboxLimits(per_call_seconds=1.0, cpu_seconds=120)
"""A replayed reward has DeepRacer's per-step budget, and two minutes for the episode."""
CHARTS = ("progress", "heatmap", "episodes", "fastest", "actions", "evaluations")
_ITERATION_RE = re.compile(r"training-simtrace/(\d+)-iteration\.csv$")
_summaries: OrderedDict[tuple, RunSummary] = OrderedDict()
_files: OrderedDict[tuple, Steps] = OrderedDict()
_cache_lock = threading.Lock()
_model_locks = tuple(threading.Lock() for _ in range(16))
"""One model's summary is brought up to date by one thread at a time: the page asks for five
charts at once, and a model without a summary should be parsed once, not five times."""
log = logging.getLogger(__name__)


@dataclass
class Logs:
    """A model's training logs, summed up: the run's summary and its action bins' names."""

    model: RacingModel
    summary: RunSummary

    @property
    def action_names(self) -> list[str]:
        return list(self.summary.bins.names)


def _track(model: RacingModel) -> Track:
    # Keyed by the file's content too: a track imported again is drawn anew.
    return _load_track(model.track_id, model.direction,
                       track_catalog().sha256(model.track_id))  # fmt: skip


@functools.lru_cache(maxsize=32)
def _load_track(track_id: str, direction: str, sha256: str) -> Track:
    """A track in one direction (cached by id, direction and the file's SHA-256: building
    one checks its geometry, ~50 ms)."""
    return track_catalog().load(track_id).in_direction(direction)


def _lru_get(cache: OrderedDict, key):
    with _cache_lock:
        value = cache.get(key)
        if value is not None:
            cache.move_to_end(key)
        return value


def _lru_put(cache: OrderedDict, key, value, size: int) -> None:
    with _cache_lock:
        cache[key] = value
        cache.move_to_end(key)
        while len(cache) > size:
            cache.popitem(last=False)


def _identity(model: RacingModel) -> tuple:
    """What the process caches key a model's data by: its id and creation time (an id alone
    can come back after a rolled-back transaction, on SQLite)."""
    return (model.pk, model.created_at.isoformat() if model.created_at else "")


def analysis_cache_clear() -> None:
    """Forget what this process keeps (the benchmark's "uncached" runs, tests)."""
    with _cache_lock:
        _summaries.clear()
        _files.clear()


def _iteration_files(store: ObjectStore, prefix: str) -> dict[int, str]:
    """The model's training sim-trace files by iteration number (one listing)."""
    out = {}
    for key in store.list(prefix + "training-simtrace/"):
        match = _ITERATION_RE.search(key)
        if match:
            out[int(match.group(1))] = key
    return out


def _stored_summary(store: ObjectStore, key: str, blank: RunSummary) -> RunSummary:
    """The summary in the store if there is one made the same way, else ``blank``."""
    try:
        summary = RunSummary.from_bytes(store.get_bytes(key), blank.bins)
    except ObjectNotFound:
        return blank
    except SummaryError as exc:
        log.warning("rebuilding the analysis summary %s: %s", key, exc)
        return blank
    return summary if summary.fits(blank.grid, blank.bins, blank.num_waypoints) else blank


def _save(store: ObjectStore, key: str, summary: RunSummary) -> None:
    """Store the summary; a store that refuses it now costs the next reader a parse, never
    the chart (the page or the iteration goes on)."""
    try:
        store.put_bytes(key, summary.to_bytes(), "application/octet-stream")
    except StoreError as exc:
        log.warning("analysis summary %s not saved: %s", key, exc)


def analysis_summary(model: RacingModel) -> RunSummary:
    """The model's whole run summed up, up to date with its logged iterations (see
    :func:`_up_to_date`; one thread per model at a time). Raises :class:`StoreError`,
    :class:`TraceError`."""
    with _model_locks[hash(_identity(model)) % len(_model_locks)]:
        return _up_to_date(model)


def _up_to_date(model: RacingModel) -> RunSummary:
    """The model's summary, up to date with its logged iterations.

    One listing of the sim-trace folder says which iterations exist. The summary comes from
    this process's cache (when it lacks at most one of them), else from the store; the
    iterations it lacks (the one the worker just wrote, or all of them for an imported or
    older model) are parsed, folded in, and the summary is stored again. A summary covering
    an iteration whose file is gone is rebuilt from the files.
    """
    track = _track(model)
    blank = RunSummary.empty(Grid.around(track.bounds()),
                             ActionBins.for_action_space(model.action_space),
                             track.num_waypoints)  # fmt: skip
    store, prefix = get_store(), keys_for(model.pk).prefix
    files = _iteration_files(store, prefix)
    summary = _lru_get(_summaries, _identity(model))
    if summary is not None and not summary.fits(blank.grid, blank.bins, blank.num_waypoints):
        summary = None  # the model's action space was edited since (before any training)
    if summary is None or len(files.keys() - summary.covered) > 1:
        # Not kept here, or kept from long ago: the store's may cover what was logged since.
        stored = _stored_summary(store, prefix + SUMMARY_NAME, blank)
        if summary is None or len(stored.covered & files.keys()) > len(summary.covered):
            summary = stored
    if not summary.covered <= files.keys():
        summary = blank
    missing = sorted(files.keys() - summary.covered)
    if missing:
        summary = summary.merged(
            summarize(parse_simtrace(store.get_bytes(files[it])), iteration=it,
                      grid=summary.grid, bins=summary.bins,
                      num_waypoints=summary.num_waypoints)
            for it in missing
        )  # fmt: skip
        _save(store, prefix + SUMMARY_NAME, summary)
    _lru_put(_summaries, _identity(model), summary, CACHED_SUMMARIES)
    return summary


def analysis_summary_update(*, model: RacingModel) -> None:
    """Fold the iterations just logged into the model's stored summary (the training
    worker calls this after each iteration, so the analysis page never parses a whole run).
    Never fails the training: a summary that cannot be made now is made by the next call,
    or by the page."""
    try:
        analysis_summary(model)
    except (StoreError, TraceError) as exc:
        log.warning("analysis summary of model %s not updated: %s", model.pk, exc)
    except Exception:  # a chart's summary is never worth hours of training
        log.exception("analysis summary of model %s not updated", model.pk)


def training_logs(model: RacingModel) -> Logs:
    """The model's training logs, summed up (see :func:`analysis_summary`)."""
    try:
        return Logs(model, analysis_summary(model))
    except (StoreError, TraceError) as exc:
        raise ServiceError(f"the model's logs could not be read: {exc}") from None


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
    if chart == "heatmap" and kind not in charts.HEATMAPS:
        raise ServiceError(f"heatmap is one of {', '.join(charts.HEATMAPS)}")
    if chart == "evaluations":
        return {"evaluations": evaluation_laps(model)}
    logs = training_logs(model)
    if chart == "progress":
        return charts.progress(logs.summary, _evaluation_progress(model))
    if chart == "heatmap":
        return {**charts.heatmap(logs.summary, kind), "actions": logs.action_names}
    if chart == "episodes":
        return charts.episodes_table(logs.summary)
    if chart == "fastest":
        return charts.fastest_laps(logs.summary)
    return {**charts.action_usage(logs.summary), "actions": logs.action_names,
            "continuous": logs.summary.bins.continuous}  # fmt: skip


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
    """One training episode's path, step by step, from its iteration's file (kept parsed
    for the next few requests: the best laps are drawn three at a time)."""
    try:
        key = keys_for(model.pk).simtrace(iteration)
    except StoreError:
        raise ServiceError("no such episode in the logs") from None
    steps = _lru_get(_files, (*_identity(model), key))
    if steps is None:
        try:
            steps = parse_simtrace(get_store().get_bytes(key))
        except ObjectNotFound:
            raise ServiceError("no such episode in the logs") from None
        except (StoreError, TraceError) as exc:
            raise ServiceError(f"the model's logs could not be read: {exc}") from None
        _lru_put(_files, (*_identity(model), key), steps, CACHED_FILES)
    path = charts.episode_path(steps, episode)
    if not path["x"]:
        raise ServiceError("no such episode in the logs")
    return path


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
    tracks_sync_for([model.track_id])  # this worker may share no disk with the web
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
