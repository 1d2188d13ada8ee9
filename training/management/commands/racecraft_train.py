"""`manage.py racecraft_train`: train a model here (no worker needed) or through the queue."""

from __future__ import annotations

from argparse import ArgumentParser
from typing import Any

from django.core.management.base import BaseCommand

from training import services
from training.management.cli import (
    add_model_arguments,
    add_queue_argument,
    mmss,
    owner_and_model,
    require_completed,
    run_or_follow,
    service_errors,
    training_progress,
)
from training.models import TrainingJob
from training.worker.training import run_training_job


class Command(BaseCommand):
    help = (
        "Train a model until its stop condition (minutes, or ready), showing the elapsed time "
        "and the latest iteration. By default the training runs in this process; Ctrl-C asks it to "
        "stop and waits for a clean end that keeps the last checkpoint. With --queue a Celery "
        "worker runs it and this command follows it (Ctrl-C stops following, not the job)."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        add_model_arguments(parser)
        add_queue_argument(parser, what="job")

    def handle(self, *args: Any, model_id: int, owner: str | None, queue: bool, **options: Any):
        user, model = owner_and_model(model_id, owner)
        with service_errors():
            job = services.training_start(model=model, user=user, enqueue=queue)
        where = "queued for a worker" if queue else "running here"
        self.stdout.write(
            f"Training job {job.pk} of model {model.pk} ({model.name}): {where}, "
            f"stop: {job.stop_condition}; on "
            f"{' + '.join(t for t, _ in model.training_tracks)}"
        )
        done = run_or_follow(job=job, queue=queue, user=user, run=run_training_job,
                             progress=training_progress, out=self.stdout)  # fmt: skip
        if done is None:
            return  # the user stopped following a queued job; it goes on in the worker
        self._report(done)
        require_completed(done, "training job")

    def _report(self, job: TrainingJob) -> None:
        why = job.stopped_by_words
        self.stdout.write(
            f"Training job {job.pk}: {job.get_status_display()}"
            + (f" ({why})" if why else "")
            + f" after {job.iterations} iterations, {job.episodes} episodes, "
            f"{mmss(job.elapsed_seconds)}"
        )
        # A failed job's error is said once, by the CommandError of require_completed.
        if job.best_iteration is not None:
            self.stdout.write(
                f"Best checkpoint: iteration {job.best_iteration}, "
                f"{job.best_eval_progress:.1f}% of a lap in evaluation"
            )
            self.stdout.write(
                f"Next: manage.py racecraft_evaluate {job.model_id}, or "
                f"manage.py racecraft_export {job.model_id} "
                f"--car physicalmodel-{job.model.name}.tar.gz"
            )
