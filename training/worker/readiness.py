"""Running a readiness check on a Celery worker (queue ``readiness``) or inline: the model's
best checkpoint through :func:`training.rl.readiness.check_readiness`, the table into the job,
the worst cells' MP4s into the store under the model's folder.

Like an evaluation it runs no user code (the check needs no reward), in a worker process that
never loaded a reward function."""

from __future__ import annotations

from training import live, services
from training.models import ReadinessCheck
from training.rl.algorithms import set_torch_threads
from training.rl.checkpoints import CheckpointError, load_checkpoint
from training.rl.evaluation import sb3_policy
from training.rl.readiness import ReadinessError, ReadinessPlan, check_readiness
from training.services.readiness import readiness_video_key
from training.storage import StoreError
from training.store import get_store, keys_for
from training.worker.common import Heartbeat, StopFlag, env_spec, fail_with

CLEAR_ERRORS = (CheckpointError, StoreError, ReadinessError)
"""Errors whose message already tells the user what went wrong."""


def run_readiness_check(check_id: int, worker: str = "", task_id: str = "") -> str:
    """Claim and run the fairest queued readiness check for the task ``task_id``; returns
    ``"completed"``, ``"failed"``, ``"skipped"`` or ``"superseded"`` (as the evaluation's)."""
    job = services.job_claim(
        job_model=ReadinessCheck, job_id=check_id, worker=worker, task_id=task_id
    )
    if job is None:
        return "skipped"
    set_torch_threads(1)  # one car, one observation a step (as an evaluation)
    model = job.model
    group = live.job_group("readiness", job.pk)
    store = get_store()

    def on_progress(p: dict) -> None:
        services.job_heartbeat(job_model=ReadinessCheck, job_id=job.pk,
                               cells_done=p["cells_done"])  # fmt: skip
        live.send(group, {"type": "job.progress", "cells_done": p["cells_done"],
                          "cells_total": p["cells_total"]})  # fmt: skip

    try:
        plan = ReadinessPlan.from_dict(job.plan or {})
        policy_model = load_checkpoint(
            store.get_bytes(keys_for(model.pk).best), services.model_metadata(model)
        )
        spec = env_spec(model, track_id=job.track_id, direction=job.direction)
        services.job_begin(job=job)
        with Heartbeat(ReadinessCheck, job.pk):
            table = check_readiness(
                lambda env: sb3_policy(policy_model), spec, plan,
                on_progress=on_progress, should_stop=StopFlag(job),
            )  # fmt: skip
        for key, mp4 in table.videos.items():
            store.put_bytes(readiness_video_key(job, key), mp4, "video/mp4")
    except Exception as exc:  # noqa: BLE001 - every failure ends the job with a message
        return fail_with(job, exc, what="readiness check", clear=CLEAR_ERRORS)
    results = table.to_json()
    completed = services.job_complete(
        job=job, results=results, verdict=table.verdict[:300],
        ready=None if table.stopped else table.ready, cells_done=len(table.cells),
        videos=sorted(table.videos),
    )  # fmt: skip
    return "completed" if completed else "superseded"
