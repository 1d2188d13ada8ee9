"""`manage.py racecraft_evaluate`: evaluate a trained model and print DeepRacer's results."""

from __future__ import annotations

from argparse import ArgumentParser
from typing import Any

from django.core.management.base import BaseCommand

from training import services
from training.management.cli import (
    add_model_arguments,
    add_queue_argument,
    add_track_argument,
    evaluation_progress,
    owner_and_model,
    require_completed,
    results_table,
    run_or_follow,
)
from training.management.race_options import (
    add_race_arguments,
    evaluation_race,
    race_errors,
    race_summary,
)
from training.models import Direction
from training.worker.evaluation import run_evaluation_job


class Command(BaseCommand):
    help = (
        "Evaluate a trained model (its best checkpoint) for 3-5 laps from the start line, "
        "with DeepRacer's penalties, and print the results table. By default it runs in this "
        "process (Ctrl-C stops it and keeps the laps driven so far); with --queue a Celery "
        "worker runs it and this command follows it. There is no --seed: an evaluation is "
        "deterministic (the car starts on the start line, the simulator is reset with seed 0 "
        "and the policy takes its most likely action), so the same model and settings drive "
        "the same laps. The training seed is racecraft_create_model --seed. The race is the "
        "model's own (its boxes or bot cars) unless --race-type or a box or bot option "
        "changes it, as the console's evaluation form does."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        add_model_arguments(parser)
        parser.add_argument("--laps", type=int, default=3, help="laps to drive, 3-5 (default 3)")
        add_track_argument(parser, default=None)
        parser.add_argument(
            "--direction",
            choices=Direction.values,
            help="driving direction (default: the model's)",
        )
        parser.add_argument(
            "--off-track-penalty",
            type=float,
            default=2.0,
            metavar="SECONDS",
            help="seconds added per off-track, 0-60 (default 2)",
        )
        parser.add_argument(
            "--crash-penalty",
            type=float,
            default=5.0,
            metavar="SECONDS",
            help="seconds added per crash, 0-60 (default 5)",
        )
        add_queue_argument(parser, what="evaluation")
        add_race_arguments(parser, evaluation=True)

    def handle(self, *args: Any, model_id: int, owner: str | None, queue: bool, **options: Any):
        user, model = owner_and_model(model_id, owner)
        race_type, race_config = evaluation_race(options, model.race_type, model.race_config)
        settings = {
            "race_type": race_type,
            "race_config": race_config,
            "track_id": options["track"],
            "direction": options["direction"],
            "laps": options["laps"],
            "off_track_penalty_s": options["off_track_penalty"],
            "crash_penalty_s": options["crash_penalty"],
        }
        with race_errors(options):
            job = services.evaluation_start(model=model, user=user, enqueue=queue, **settings)
        where = "queued for a worker" if queue else "running here"
        self.stdout.write(
            f"Evaluation {job.pk} of model {model.pk} ({model.name}): {where}, {job.laps} laps "
            f"on {job.track_id} ({job.direction}), {race_summary(job.race_type, job.race_config)}"
        )
        done = run_or_follow(job=job, queue=queue, user=user, run=run_evaluation_job,
                             progress=evaluation_progress, out=self.stdout)  # fmt: skip
        if done is None:
            return
        if done.lap_rows:
            self.stdout.write(results_table(done))
        completed = done.results.get("completed_laps", 0) if isinstance(done.results, dict) else 0
        stopped = " (stopped early)" if done.results.get("stopped") else ""
        self.stdout.write(
            f"Evaluation {done.pk}: {done.get_status_display()}{stopped}, "
            f"{completed}/{done.laps} laps completed"
        )
        require_completed(done, "evaluation")
