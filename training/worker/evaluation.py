"""Running an evaluation job on a Celery worker (or inline, for the command line): 3-5 laps of
the model's best checkpoint, DeepRacer's metrics and sim-trace, an MP4, live frames.

The logs go where DeepRacer-for-Cloud puts them: ``evaluation-<stamp>/evaluation-simtrace/
0-iteration.csv`` and ``metrics/EvaluationMetrics-<stamp>.json``, ``<stamp>`` the job's start
(``YYYYMMDDhhmmss`` UTC), kept in ``EvaluationJob.log_stamp``."""

from __future__ import annotations

import json

from django.utils import timezone

from training import live, services
from training.interchange.layout import evaluation_stamp
from training.models import EvaluationJob
from training.rl.algorithms import set_torch_threads
from training.rl.checkpoints import CheckpointError, load_checkpoint
from training.rl.evaluation import EvaluationSettings, evaluate, sb3_policy
from training.services.racing import race_config
from training.storage import StoreError
from training.store import get_store, keys_for
from training.worker.common import Heartbeat, StopFlag, csv_text, env_spec, fail_with

CLEAR_ERRORS = (CheckpointError, StoreError)
"""Errors whose message already tells the user what went wrong."""


def run_evaluation_job(evaluation_id: int, worker: str = "", task_id: str = "") -> str:
    """Claim and run the fairest queued evaluation for the task ``task_id`` sent for
    ``evaluation_id`` (:mod:`training.services.job_queue`); returns ``"completed"``, ``"failed"``,
    ``"skipped"`` or ``"superseded"`` (as :func:`~training.worker.training.run_training_job`)."""
    job = services.job_claim(
        job_model=EvaluationJob, job_id=evaluation_id, worker=worker, task_id=task_id
    )
    if job is None:
        return "skipped"
    # One car, one observation a step: a second thread only waits, and on cores shared with
    # trainers its spinning costs far more than it gives.
    set_torch_threads(1)
    model = job.model
    group = live.job_group("evaluation", job.pk)
    store, keys = get_store(), keys_for(model.pk)
    laps_done = {"n": 0}

    def on_progress(p: dict) -> None:
        if p["laps_done"] != laps_done["n"]:
            laps_done["n"] = p["laps_done"]
            services.job_heartbeat(job_model=EvaluationJob, job_id=job.pk,
                                   laps_done=p["laps_done"])  # fmt: skip
            live.send(group, {"type": "job.progress", "laps_done": p["laps_done"]})

    frames = live.FramePublisher(group)
    try:
        policy_model = load_checkpoint(store.get_bytes(keys.best), services.model_metadata(model))
        settings = EvaluationSettings(laps=job.laps, off_track_penalty_s=job.off_track_penalty_s,
                                      crash_penalty_s=job.crash_penalty_s)  # fmt: skip
        services.job_begin(job=job)
        with Heartbeat(EvaluationJob, job.pk):
            report = evaluate(
                sb3_policy(policy_model),
                env_spec(
                    model,
                    track_id=job.track_id,
                    direction=job.direction,
                    race=race_config(job.race_type, job.race_config),
                    conditions=job.conditions,  # {}: clean, unless a league event says
                    conditions_seed=job.conditions_seed,
                ),
                settings,
                on_progress=on_progress,
                should_stop=StopFlag(job),
                on_frame=frames.publish,
                frames_wanted=frames.watched,
            )
        stamp = evaluation_stamp(job.started_at or timezone.now())
        store.put_bytes(keys.evaluation_metrics(stamp),
                        json.dumps(report.metrics_json()).encode(), "application/json")  # fmt: skip
        store.put_bytes(keys.evaluation_simtrace(stamp), csv_text(report.rows).encode(),
                        "text/csv")  # fmt: skip
        services.evaluation_record_logs(job=job, stamp=stamp)
        if report.video_mp4:
            store.put_bytes(keys.video(job.pk), report.video_mp4, "video/mp4")
    except Exception as exc:  # noqa: BLE001 - every failure ends the job with a message
        return fail_with(job, exc, what="evaluation", clear=CLEAR_ERRORS)
    finally:
        frames.close()
    completed = services.job_complete(
        job=job, results=report.to_json(), laps_done=report.completed_laps,
        has_video=bool(report.video_mp4),
    )  # fmt: skip
    if completed:
        live.send(group, {"type": "job.status", "status": "COMPLETED",
                          "results": report.to_json()})  # fmt: skip
    return "completed" if completed else "superseded"
