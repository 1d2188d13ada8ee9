"""Running a training job on a Celery worker (or inline, for the command line).

The training loop (:mod:`training.rl.runner`) knows nothing of Django; this module gives it
where rollouts run (:func:`~training.worker.common.rollout_backend`) and :class:`JobHooks`,
which turn its reports into rows (metrics), stored objects (checkpoints, sim-traces,
DeepRacer's metrics files) and live messages. State changes go through the services.
"""

from __future__ import annotations

import json
import logging
import time

from django.conf import settings
from django.db import transaction

from racing.rules import STATUS_LABELS, Status
from training import live, selectors, services
from training.interchange.logbook import LoggedIteration, TrainingLog
from training.models import EpisodeMetric, IterationMetric, RacingModel, TrainingJob
from training.rl.algorithms import DeviceError
from training.rl.checkpoints import CheckpointError
from training.rl.hyperparams import parse_hyperparameters
from training.rl.runner import IterationResult, TrainingConfig, TrainingHooks, train
from training.rollout.vecenv import RolloutError
from training.sandbox import SandboxError
from training.services.analysis import analysis_summary_update
from training.services.downloads import car_archive_build
from training.storage import ObjectNotFound, StoreError
from training.store import get_store, keys_for
from training.worker.common import (
    Heartbeat,
    StopFlag,
    env_spec,
    fail_with,
    rollout_backend,
)

log = logging.getLogger(__name__)
EPISODE_COUNT_EVERY_S = 5.0
"""How often a running job records how many episodes have finished, seconds."""
CLEAR_ERRORS = (RolloutError, SandboxError, CheckpointError, StoreError, DeviceError)
"""Errors whose message already tells the user what went wrong."""


class JobHooks(TrainingHooks):
    """Database rows, stored objects and live messages for one training job.

    Episodes are logged as DeepRacer logs them (:class:`~training.interchange.logbook.
    TrainingLog`): iterations of ``num_episodes_between_training`` episodes in the order they
    finished, so an :class:`EpisodeMetric`'s ``iteration`` is the log's iteration (1-based;
    the sim-trace file ``<iteration - 1>-iteration.csv``), not the policy update it followed.
    """

    def __init__(self, job: TrainingJob) -> None:
        self.job = job
        self.model = job.model
        self.keys = keys_for(self.model.pk)
        self.store = get_store()
        self.group = live.job_group("training", job.pk)
        self.frames = live.FramePublisher(self.group)
        self.should_stop = StopFlag(job)
        hp = parse_hyperparameters(self.model.hyperparameters, self.model.algorithm)
        # A resumed job numbers on from the iterations and episodes it already recorded; its
        # log starts a fresh sim-trace file (never rewrites a file of the earlier run).
        per = hp.num_episodes_between_training
        logged = EpisodeMetric.objects.filter(job=job, phase="training").count()
        self.log = TrainingLog(per, logged_episodes=-(-logged // per) * per)
        self._finished = job.episodes  # training episodes finished so far
        self._counted_at = 0.0
        self._iteration_offset = job.iterations
        last = IterationMetric.objects.filter(job=job).order_by("-iteration").first()
        self._elapsed_offset = last.elapsed_s if last else 0.0

    # ---- polled during rollouts
    def frames_wanted(self) -> bool:
        return self.frames.watched()

    def on_frame(self, frame: dict) -> None:
        if isinstance(frame.get("iteration"), int):  # numbered on from a resumed job's
            frame = {**frame, "iteration": frame["iteration"] + self._iteration_offset}
        self.frames.publish(frame)

    def on_episode(self, entry: dict) -> None:
        self.log.add_entry(entry)
        self._finished += 1
        now = time.monotonic()
        if now - self._counted_at >= EPISODE_COUNT_EVERY_S:  # the page and the CLI show it
            self._counted_at = now
            services.job_heartbeat(job_model=TrainingJob, job_id=self.job.pk,
                                   episodes=self._finished)  # fmt: skip

    # ---- once per iteration
    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list[list]) -> None:
        n = result.iteration + self._iteration_offset
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
        self.log.add_rows(rows)
        ev = result.evaluation
        with transaction.atomic():
            point = IterationMetric.objects.create(
                job=self.job, iteration=n, episodes=result.episodes, steps=result.steps,
                total_steps=result.total_steps, train_reward=result.train_reward,
                train_progress=result.train_progress, eval_progress=result.eval_progress,
                eval_reward=float(sum(ev.rewards) / max(1, len(ev.rewards))),
                eval_laps_completed=sum(len(t) for t in ev.lap_times),
                is_best=result.best, elapsed_s=result.elapsed_s + self._elapsed_offset,
                rollout_s=result.rollout_s,
                update_s=result.update_s, eval_s=result.eval_s,
            ).as_point()  # fmt: skip
            self._store_log(self.log.take(), evaluation=ev)
            progress = {"iterations": n, "total_steps": result.total_steps,
                        "episodes": self._finished}  # fmt: skip
            if result.best:
                progress.update(best_iteration=n, best_eval_progress=result.eval_progress)
            services.job_heartbeat(job_model=TrainingJob, job_id=self.job.pk, **progress)
            services.model_mark_checkpoint(model=self.model)
        self._write_training_metrics()
        analysis_summary_update(model=self.model)
        live.send(self.group, {"type": "job.metrics", "point": point})

    def finish(self) -> None:
        """Log the episodes still queued when training ends (a last, shorter iteration)."""
        with transaction.atomic():
            self._store_log(self.log.take(final=True), evaluation=None)
            services.job_heartbeat(job_model=TrainingJob, job_id=self.job.pk,
                                   episodes=self.log.logged)  # fmt: skip
        self._write_training_metrics()

    def _store_log(self, iterations: list[LoggedIteration], evaluation) -> None:
        """Sim-trace files and episode rows of the logged iterations; then, after the last
        training entry, the evaluation episodes of the policy update (DeepRacer's order)."""
        rows: list[EpisodeMetric] = []
        for it in iterations:
            self.store.put_bytes(self.keys.simtrace(it.number), it.simtrace_csv().encode(),
                                 "text/csv")  # fmt: skip
            rows += [_episode_row(self.job, it.number + 1, e.entry) for e in it.episodes]
        last = rows[-1] if rows else self._last_training_row()
        if evaluation is not None and last is not None:
            rows += _evaluation_rows(self.job, last, evaluation)
        EpisodeMetric.objects.bulk_create(rows)

    def _last_training_row(self) -> EpisodeMetric | None:
        return EpisodeMetric.objects.filter(job=self.job, phase="training").order_by("-pk").first()

    def _write_training_metrics(self) -> None:
        entries = [m.as_deepracer() for m in EpisodeMetric.objects.filter(job=self.job)]
        body = {"metrics": entries, "version": 2, "best_model_metric": "progress"}
        self.store.put_bytes(
            self.keys.training_metrics, json.dumps(body).encode(), "application/json"
        )

    def close(self) -> None:
        self.frames.close()


def _episode_row(job: TrainingJob, iteration: int, e: dict) -> EpisodeMetric:
    """A row from a worker's metrics entry (untrusted: every value checked)."""

    def num(key: str, default: int = 0) -> int:
        value = e.get(key, default)
        return int(value) if isinstance(value, int | float) else default

    return EpisodeMetric(
        job=job,
        iteration=iteration,
        episode=max(0, num("episode")),
        trial=max(0, num("trial")),
        phase="training",
        reward_score=num("reward_score"),
        completion_percentage=min(100, max(0, num("completion_percentage"))),
        episode_status=str(e.get("episode_status", ""))[:20],
        elapsed_time_in_milliseconds=max(0, num("elapsed_time_in_milliseconds")),
        start_time=max(0, num("start_time")),
        metric_time=max(0, num("metric_time")),
        track=str(e.get("track", ""))[:64] if job.model.extra_tracks else "",
    )


def _evaluation_rows(job: TrainingJob, last: EpisodeMetric, ev) -> list[EpisodeMetric]:
    """The evaluation episodes after an update, as TrainingMetrics ``evaluation`` entries:
    numbered like the last training entry; times are the lap's, when it finished one."""
    rows = []
    # Evaluation env i drives the model's track i (mod their number): EnvSpec.for_env.
    tracks = [t for t, _ in job.model.training_tracks] if job.model.extra_tracks else [""]
    for i, (progress, status, laps, reward) in enumerate(
        zip(ev.progress, ev.statuses, ev.lap_times, ev.rewards, strict=True)
    ):
        label = STATUS_LABELS.get(Status(status), "") if status in _STATUSES else ""
        rows.append(EpisodeMetric(
            job=job, iteration=last.iteration, episode=last.episode, trial=last.trial,
            phase="evaluation", reward_score=int(round(reward)),
            completion_percentage=min(100, max(0, int(progress))), episode_status=label,
            elapsed_time_in_milliseconds=int(round(sum(laps) * 1000)),
            start_time=0, metric_time=0, track=tracks[i % len(tracks)],
        ))  # fmt: skip
    return rows


_STATUSES = {s.value for s in Status}


def _initial_checkpoint(
    job: TrainingJob, model: RacingModel
) -> tuple[bytes | None, float | None, str, int]:
    """What the job starts from: ``(checkpoint, best score so far, the same in words, "stop
    when ready" streak so far)``.

    A model trained before (a retried or restarted job, or a failed model trained again)
    resumes from its last checkpoint and keeps its best one unless an iteration beats the best
    evaluation progress so far; a job that resumes its own last checkpoint (its worker was
    lost) also counts on from its streak; a clone or an imported model starts from the
    checkpoint it was given; a new model from a fresh network."""
    store, keys = get_store(), keys_for(model.pk)
    trained = TrainingJob.objects.filter(model=model, iterations__gt=0)
    last_job = trained.order_by("-started_at", "-pk").first()
    if model.has_checkpoint and last_job is not None:
        try:
            checkpoint = store.get_bytes(keys.last)
        except ObjectNotFound:
            checkpoint = None
        if checkpoint is not None:
            best_job = trained.filter(best_iteration__isnull=False)
            best_job = best_job.order_by("-best_eval_progress", "-pk").first()
            own = last_job.pk == job.pk
            where = "its own" if own else f"job #{last_job.pk}'s"
            text = f"resumed from {where} last checkpoint (iteration {last_job.iterations})"
            streak = _streak_so_far(job) if own else 0
            best = None
            if best_job is not None:
                best = best_job.best_eval_progress
                text += (
                    f"; best so far {best:.1f}% evaluation progress (job "
                    f"#{best_job.pk}, iteration {best_job.best_iteration}), kept unless beaten"
                )
            if streak:
                text += f"; ready streak {streak} of {job.stop_when_ready} carried on"
            return checkpoint, best, text, streak
    try:
        checkpoint = store.get_bytes(keys.checkpoint("initial"))
    except ObjectNotFound:
        return None, None, "started from a new network", 0
    if model.parent_id is not None:
        return checkpoint, None, f"started from the checkpoint of model #{model.parent_id}", 0
    return checkpoint, None, "started from the imported model's checkpoint", 0


def _streak_so_far(job: TrainingJob) -> int:
    """A job's "stop when ready" count so far: its latest recorded iterations in a row whose
    evaluation completed every lap (as its page shows it); 0 when it does not stop when ready."""
    if not job.stop_when_ready:
        return 0
    return selectors.clean_streak(selectors.chart_points(job))


def run_training_job(job_id: int, worker: str = "", task_id: str = "") -> str:
    """Claim and run the fairest queued training job for the task ``task_id`` sent for
    ``job_id`` (:mod:`training.services.job_queue`); returns ``"completed"``, ``"failed"``,
    ``"skipped"`` (another worker has it, or it was canceled) or ``"superseded"`` (it ended
    meanwhile, e.g. failed by the orphan reaper; its result is not recorded twice)."""
    job = services.job_claim(job_model=TrainingJob, job_id=job_id, worker=worker, task_id=task_id)
    if job is None:
        return "skipped"
    model = job.model
    hooks = JobHooks(job)
    try:
        checkpoint, best_score, started_from, streak = _initial_checkpoint(job, model)
        services.job_resumed_from(job=job, description=started_from)
        # A resumed job trains for the time it has left.
        max_minutes = max(0.5, job.max_minutes - hooks._elapsed_offset / 60)
        config = TrainingConfig(
            spec=env_spec(model, conditions=model.conditions),  # the world outside, if on
            algorithm=model.algorithm,
            network=model.neural_network,
            hyperparameters=parse_hyperparameters(model.hyperparameters, model.algorithm),
            max_minutes=max_minutes,
            stop_when_ready=job.stop_when_ready,
            clean_streak=streak,
            reward_source=model.reward_function,
            seed=model.seed,
            initial_checkpoint=checkpoint,
            best_score=best_score,
            rollouts=rollout_backend(),
            device=settings.RACECRAFT_TORCH_DEVICE,
        )
        services.job_begin(job=job)
        with Heartbeat(TrainingJob, job.pk):
            summary = train(config, hooks)
            hooks.finish()
    except Exception as exc:  # noqa: BLE001 - every failure ends the job with a message
        return fail_with(job, exc, what="training", clear=CLEAR_ERRORS)
    finally:
        hooks.close()
    model.refresh_from_db()
    if model.has_checkpoint:
        _export_car(model)
    completed = services.job_complete(
        job=job,
        on_model_error="training stopped before the first iteration finished",
        stopped_by=summary.stopped_by,
    )
    return "completed" if completed else "superseded"


def _export_car(model: RacingModel) -> None:
    """Write the car archive (``agent/model.pb`` + ``model_metadata.json``) from the best
    checkpoint, so the download is ready at once."""
    try:
        car_archive_build(model)
    except Exception:  # noqa: BLE001 - the download rebuilds it on demand
        log.warning("could not export model %s for the car", model.pk, exc_info=True)
