"""What the Celery tasks do: run a training or an evaluation job from its database row.

The runner knows nothing of Django; :class:`JobHooks` turns its reports into rows (metrics),
stored objects (checkpoints, sim-traces, DeepRacer's metrics files) and live messages.
"""

from __future__ import annotations

import json
import logging
import socket
import threading
import time

from django.db import transaction
from django.utils import timezone

from racing.simtrace import SIMTRACE_COLUMNS
from training.interchange.export import build_car_archive, export_onnx
from training.models import (
    EpisodeMetric,
    EvaluationJob,
    IterationMetric,
    JobStatus,
    RacingModel,
    TrainingJob,
)
from training.rl.checkpoints import CheckpointError
from training.rl.evaluation import EvaluationSettings, evaluate, sb3_policy
from training.rl.hyperparams import parse_hyperparameters
from training.rl.runner import IterationResult, TrainingConfig, TrainingHooks, train
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import RolloutError
from training.sandbox import SandboxError
from training.services import _settle_model, job_fail, model_metadata
from training.signals import evaluation_finished
from training.storage import ObjectNotFound, StoreError
from training.store import get_store, keys_for
from training.worker import live

log = logging.getLogger(__name__)
STOP_POLL_S = 1.0
HEARTBEAT_S = 15.0


class Heartbeat:
    """Stamps ``heartbeat_at`` every ``HEARTBEAT_S`` seconds from a thread of its own while a
    job runs, however long one policy update takes. If the worker process dies, the stamps
    stop and the orphan reaper (services.jobs_reap_orphans) marks the job failed."""

    def __init__(self, job_model, job_id: int, every: float = HEARTBEAT_S) -> None:
        self._rows = job_model.objects.filter(pk=job_id)
        self._every = every
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"heartbeat-{job_id}", daemon=True)

    def _run(self) -> None:
        from django.db import connection

        try:
            while not self._stop.wait(self._every):
                try:
                    self._rows.update(heartbeat_at=timezone.now())
                except Exception:  # noqa: BLE001 - a missed beat is retried on the next one
                    log.warning("could not record a heartbeat", exc_info=True)
        finally:
            connection.close()

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def env_spec(model: RacingModel, *, track_id: str | None = None, direction: str | None = None):
    from django.conf import settings

    return EnvSpec(
        track=track_id or model.track_id,
        track_dirs=(str(settings.RACECRAFT_TRACKS_DIR),),
        direction=direction or model.direction,
        action_space=model.action_space,
        sensors=tuple(model.sensors),
    )


def csv_text(rows: list[list]) -> str:
    from racing.simtrace import TraceRow

    lines = [",".join(SIMTRACE_COLUMNS)]
    for row in rows:
        try:
            lines.append(TraceRow(*row).format())
        except (TypeError, ValueError):
            continue  # a malformed row from a worker is dropped, never trusted
    return "\n".join(lines) + "\n"


class JobHooks(TrainingHooks):
    """Database rows, stored objects and live messages for one training job."""

    def __init__(self, job: TrainingJob) -> None:
        self.job = job
        self.model = job.model
        self.keys = keys_for(self.model.pk)
        self.store = get_store()
        self.group = live.job_group("training", job.pk)
        self.frames = live.FramePublisher(self.group)
        self._stop_checked = 0.0
        self._stop = False
        self._episodes: list[dict] = []
        self._episode_count = 0

    # ---- polled during rollouts
    def should_stop(self) -> bool:
        now = time.monotonic()
        if now - self._stop_checked >= STOP_POLL_S:
            self._stop_checked = now
            self._stop = TrainingJob.objects.filter(pk=self.job.pk, stop_requested=True).exists()
        return self._stop

    def frames_wanted(self) -> bool:
        return self.frames.watched()

    def on_frame(self, frame: dict) -> None:
        self.frames.publish(frame)

    def on_episode(self, entry: dict) -> None:
        self._episodes.append(entry)

    # ---- once per iteration
    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list[list]) -> None:
        n = result.iteration
        store, keys = self.store, self.keys
        store.put_bytes(keys.last, checkpoint)
        if result.best:
            store.put_bytes(keys.best, checkpoint)
        store.put_bytes(
            keys.checkpoints_index,
            json.dumps(
                {"best_checkpoint": {"name": "best.zip"}, "last_checkpoint": {"name": "last.zip"}}
            ).encode(),  # fmt: skip
            "application/json",
        )
        store.put_bytes(keys.simtrace(n - 1), csv_text(rows).encode(), "text/csv")
        episodes, self._episodes = self._episodes, []
        ev = result.evaluation
        with transaction.atomic():
            IterationMetric.objects.create(
                job=self.job, iteration=n, episodes=result.episodes, steps=result.steps,
                total_steps=result.total_steps, train_reward=result.train_reward,
                train_progress=result.train_progress, eval_progress=result.eval_progress,
                eval_reward=float(sum(ev.rewards) / max(1, len(ev.rewards))),
                eval_laps_completed=sum(len(t) for t in ev.lap_times),
                is_best=result.best, elapsed_s=result.elapsed_s, rollout_s=result.rollout_s,
                update_s=result.update_s, eval_s=result.eval_s,
            )  # fmt: skip
            new_rows = []
            for entry in episodes:
                if isinstance(entry, dict):
                    new_rows.append(_episode_row(self.job, n, entry, self._episode_count))
                    self._episode_count += 1
            EpisodeMetric.objects.bulk_create(new_rows)
            updates = {
                "iterations": n,
                "total_steps": result.total_steps,
                "episodes": self._episode_count,
                "heartbeat_at": timezone.now(),
            }
            if result.best:
                updates.update(best_iteration=n, best_eval_progress=result.eval_progress)
            TrainingJob.objects.filter(pk=self.job.pk).update(**updates)
            if not self.model.has_checkpoint:
                RacingModel.objects.filter(pk=self.model.pk).update(has_checkpoint=True)
                self.model.has_checkpoint = True
        self._write_training_metrics()
        point = IterationMetric.objects.get(job=self.job, iteration=n).as_point()
        live.send(self.group, {"type": "job.metrics", "point": point})

    def _write_training_metrics(self) -> None:
        entries = [
            m.as_deepracer()
            for m in EpisodeMetric.objects.filter(job=self.job).order_by("episode", "pk")
        ]
        body = {"metrics": entries, "version": 2, "best_model_metric": "progress"}
        self.store.put_bytes(
            self.keys.training_metrics, json.dumps(body).encode(), "application/json"
        )

    def close(self) -> None:
        self.frames.close()


def _episode_row(job: TrainingJob, iteration: int, e: dict, number: int) -> EpisodeMetric:
    """A row from a worker's metrics entry (untrusted: every value checked)."""

    def num(key: str, default: int = 0) -> int:
        value = e.get(key, default)
        return int(value) if isinstance(value, int | float) else default

    return EpisodeMetric(
        job=job,
        iteration=iteration,
        episode=number,
        phase="training",
        reward_score=num("reward_score"),
        completion_percentage=min(100, max(0, num("completion_percentage"))),
        episode_status=str(e.get("episode_status", ""))[:20],
        elapsed_time_in_milliseconds=max(0, num("elapsed_time_in_milliseconds")),
        start_time=max(0, num("start_time")),
        metric_time=max(0, num("metric_time")),
    )


def _set_status(job, status: str, **extra) -> None:
    """Move the job on, unless a stop request already moved it to STOPPING."""
    rows = type(job).objects.exclude(status=JobStatus.STOPPING).filter(pk=job.pk)
    if not rows.update(status=status, **extra):
        return
    job.status = status
    live.send(live.job_group(_kind(job), job.pk), {"type": "job.status", "status": status})


def _kind(job) -> str:
    return "training" if isinstance(job, TrainingJob) else "evaluation"


def _claim(job_model, job_id: int, worker: str):
    """Move a queued job to INITIALIZING; None when it was canceled or already taken."""
    with transaction.atomic():
        job = job_model.objects.select_for_update().select_related("model").get(pk=job_id)
        if job.status != JobStatus.QUEUED:
            return None
        now = timezone.now()
        job.status = JobStatus.INITIALIZING
        job.started_at = now
        job.heartbeat_at = now
        job.worker = (worker or socket.gethostname())[:255]
        job.save(update_fields=["status", "started_at", "heartbeat_at", "worker"])
    return job


def _remote_rollouts() -> dict | None:
    """Rollouts on the ``simulation`` queue when RACECRAFT_REMOTE_ROLLOUT_SLOTS > 0."""
    from django.conf import settings

    slots = int(getattr(settings, "RACECRAFT_REMOTE_ROLLOUT_SLOTS", 0))
    if slots <= 0:
        return None
    return {"redis_url": settings.REDIS_URL, "prefix": settings.REDIS_PREFIX or "",
            "slots": slots}  # fmt: skip


def run_training_job(job_id: int, worker: str = "") -> str:
    job = _claim(TrainingJob, job_id, worker)
    if job is None:
        return "skipped"
    model = job.model
    RacingModel.objects.filter(pk=model.pk).update(status=RacingModel.Status.TRAINING)
    hooks = JobHooks(job)
    try:
        store, keys = get_store(), keys_for(model.pk)
        initial = None
        try:
            initial = store.get_bytes(keys.checkpoint("initial"))
        except ObjectNotFound:
            pass
        config = TrainingConfig(
            spec=env_spec(model),
            algorithm=model.algorithm,
            network=model.neural_network,
            hyperparameters=parse_hyperparameters(model.hyperparameters, model.algorithm),
            max_minutes=job.max_minutes,
            reward_source=model.reward_function,
            seed=model.seed,
            initial_checkpoint=initial,
            remote=_remote_rollouts(),
        )
        _set_status(job, JobStatus.IN_PROGRESS)
        with Heartbeat(TrainingJob, job.pk):
            summary = train(config, hooks)
    except (RolloutError, SandboxError, CheckpointError, StoreError) as exc:
        job_fail(job=job, error=str(exc))
        return "failed"
    except Exception as exc:
        log.exception("training job %s failed", job_id)
        job_fail(job=job, error=f"training failed: {type(exc).__name__}: {exc}")
        return "failed"
    finally:
        hooks.close()
    model.refresh_from_db()
    if model.has_checkpoint:
        _export_car(model)
    with transaction.atomic():  # the job and its model change state together
        _settle_model(model, "training stopped before the first iteration finished")
        TrainingJob.objects.filter(pk=job.pk).update(
            status=JobStatus.COMPLETED, finished_at=timezone.now(), stopped_by=summary.stopped_by
        )
    live.send(live.job_group("training", job.pk), {"type": "job.status", "status": "COMPLETED"})
    return "completed"


def _export_car(model: RacingModel) -> None:
    """Write export/car.tar.gz (model_metadata.json + model.onnx) from the best checkpoint."""
    store, keys = get_store(), keys_for(model.pk)
    try:
        from training.rl.checkpoints import load_checkpoint

        metadata = model_metadata(model)
        policy = load_checkpoint(store.get_bytes(keys.best), metadata)
        store.put_bytes(keys.car_export, build_car_archive(metadata, export_onnx(policy)))
    except Exception:  # noqa: BLE001 - the download rebuilds it on demand
        log.warning("could not export model %s for the car", model.pk, exc_info=True)


def run_evaluation_job(evaluation_id: int, worker: str = "") -> str:
    job = _claim(EvaluationJob, evaluation_id, worker)
    if job is None:
        return "skipped"
    model = job.model
    group = live.job_group("evaluation", job.pk)
    store, keys = get_store(), keys_for(model.pk)
    try:
        from training.rl.checkpoints import load_checkpoint

        policy_model = load_checkpoint(store.get_bytes(keys.best), model_metadata(model))
        settings = EvaluationSettings(laps=job.laps, off_track_penalty_s=job.off_track_penalty_s,
                                      crash_penalty_s=job.crash_penalty_s)  # fmt: skip
        _set_status(job, JobStatus.IN_PROGRESS)
        state = {"laps": 0, "checked": 0.0, "stop": False}

        def on_progress(p: dict) -> None:
            if p["laps_done"] != state["laps"]:
                state["laps"] = p["laps_done"]
                EvaluationJob.objects.filter(pk=job.pk).update(
                    laps_done=p["laps_done"], heartbeat_at=timezone.now()
                )
                live.send(group, {"type": "job.progress", "laps_done": p["laps_done"]})

        def should_stop() -> bool:
            now = time.monotonic()
            if now - state["checked"] >= STOP_POLL_S:
                state["checked"] = now
                state["stop"] = EvaluationJob.objects.filter(
                    pk=job.pk, stop_requested=True
                ).exists()
            return state["stop"]

        frames = live.FramePublisher(group)
        try:
            with Heartbeat(EvaluationJob, job.pk):
                report = evaluate(
                    sb3_policy(policy_model),
                    env_spec(model, track_id=job.track_id, direction=job.direction),
                    settings,
                    on_progress=on_progress,
                    should_stop=should_stop,
                    on_frame=frames.publish,
                    frames_wanted=frames.watched,
                )
        finally:
            frames.close()
        store.put_bytes(keys.evaluation_metrics(job.pk),
                        json.dumps(report.metrics_json()).encode(), "application/json")  # fmt: skip
        store.put_bytes(keys.evaluation_simtrace(job.pk, 0), csv_text(report.rows).encode(),
                        "text/csv")  # fmt: skip
        if report.video_mp4:
            store.put_bytes(keys.video(job.pk), report.video_mp4, "video/mp4")
    except (CheckpointError, StoreError) as exc:
        job_fail(job=job, error=str(exc))
        return "failed"
    except Exception as exc:
        log.exception("evaluation %s failed", evaluation_id)
        job_fail(job=job, error=f"evaluation failed: {type(exc).__name__}: {exc}")
        return "failed"
    with transaction.atomic():
        _settle_model(model)
        EvaluationJob.objects.filter(pk=job.pk).update(
            status=JobStatus.COMPLETED, finished_at=timezone.now(), results=report.to_json(),
            laps_done=report.completed_laps, has_video=bool(report.video_mp4),
        )  # fmt: skip
    live.send(group, {"type": "job.status", "status": "COMPLETED", "results": report.to_json()})
    evaluation_finished.send(sender=EvaluationJob, evaluation_id=job.pk)
    return "completed"
