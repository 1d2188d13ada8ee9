"""`manage.py racecraft_race`: race 2-4 models head to head, here, and print the results."""

from __future__ import annotations

import json
from argparse import ArgumentParser
from pathlib import Path
from typing import Any

from django.core.management.base import BaseCommand, CommandError
from django.utils import timezone

from training.formatting import format_lap_s
from training.interchange.layout import ModelKeys, evaluation_stamp
from training.management.cli import add_track_argument, service_errors
from training.models import Direction
from training.rl.race import RaceReport
from training.services import model_metadata, race_plan
from training.worker.common import csv_text
from training.worker.race import race_models


class Command(BaseCommand):
    help = (
        "Race 2-4 models head to head on one track, in this process, and print the results "
        "(with --json, one JSON object: the winner's model id, then each car's position, "
        "laps, lap times, total time, race progress, off-tracks, crashes and resets). Each "
        "model drives with its own sensors and action space from its best checkpoint; the "
        "others are in its cameras and LIDAR. Touching another car from behind is a crash, "
        "with the crash penalty. The grid is staggered, pole in the order the models are "
        "given (--round N rotates it). A model that cannot race is out with the reason. The "
        "same models, settings and --seed give the same race."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("model_ids", type=int, nargs="+", metavar="MODEL_ID")
        add_track_argument(parser, default=None)
        parser.add_argument(
            "--direction",
            choices=Direction.values,
            default="native",
            help="driving direction (default: native)",
        )
        parser.add_argument("--laps", type=int, default=3, help="laps, 1-10 (default 3)")
        parser.add_argument(
            "--bots",
            type=int,
            default=0,
            metavar="K",
            help="bot cars on the track, 0-6 (default 0)",
        )
        parser.add_argument(
            "--bot-speed",
            type=float,
            default=0.75,
            metavar="M/S",
            help="bot cars' speed, 0.2-6 m/s (default 0.75)",
        )
        parser.add_argument("--seed", type=int, default=0, help="the race's seed (default 0)")
        parser.add_argument(
            "--round",
            type=int,
            default=0,
            metavar="N",
            help="rotate the grid N places (default 0: pole to the first)",
        )
        parser.add_argument(
            "--off-track-penalty",
            type=float,
            default=5.0,
            metavar="SECONDS",
            help="seconds a car stands after an off-track, 0-60 (default 5)",
        )
        parser.add_argument(
            "--crash-penalty",
            type=float,
            default=5.0,
            metavar="SECONDS",
            help="seconds a car stands after a crash, 0-60 (default 5)",
        )
        parser.add_argument(
            "--time-limit",
            type=float,
            default=None,
            metavar="SECONDS",
            help="race clock limit, 10-3600 s (default 90 s a lap)",
        )
        parser.add_argument(
            "--video",
            type=Path,
            metavar="FILE",
            help="write the broadcast MP4 (all cars, timing tower) here",
        )
        parser.add_argument(
            "--traces",
            type=Path,
            metavar="DIR",
            help="write each car's sim-trace in DeepRacer's evaluation format, as "
            "DIR/<model id>/evaluation-<stamp>/evaluation-simtrace/0-iteration.csv, with "
            "its model/model_metadata.json (deepracer-utils reads DIR/<model id> as a model "
            "folder)",
        )
        parser.add_argument("--json", action="store_true", help="print one JSON object")

    def handle(self, *args: Any, model_ids: list[int], **options: Any) -> None:
        if options["track"] is None:
            raise CommandError("--track is required")
        video = options["video"]
        if video is not None and not Path(video).parent.is_dir():
            raise CommandError(f"--video {video}: its folder does not exist")
        with service_errors("race"):
            plan = race_plan(
                model_ids=model_ids,
                track_id=options["track"],
                direction=options["direction"],
                laps=options["laps"],
                bots=options["bots"],
                bot_speed=options["bot_speed"],
                seed=options["seed"],
                round_number=options["round"],
                off_track_penalty_s=options["off_track_penalty"],
                crash_penalty_s=options["crash_penalty"],
                time_limit_s=options["time_limit"],
                record_video=options["video"] is not None,
            )
        report = race_models(
            plan.models,
            track_id=plan.track_id,
            direction=plan.direction,
            settings=plan.settings,
            race=plan.race,
        )
        if options["video"] is not None and report.video_mp4:
            Path(options["video"]).write_bytes(report.video_mp4)
        if options["traces"] is not None:
            _write_traces(Path(options["traces"]), report, plan.models)
        if options["json"]:
            data = report.to_json()
            data.update(
                track=plan.track_id,
                direction=plan.direction,
                seed=plan.settings.seed,
                bots=plan.race.number_of_bots if plan.race.has_bots else 0,
                bot_speed=plan.race.bot_speed if plan.race.has_bots else None,
            )
            self.stdout.write(json.dumps(data))
            return
        self.stdout.write(_table(report))


def _write_traces(folder: Path, report: RaceReport, models) -> None:  # noqa: ANN001
    """Each car's sim-trace where deepracer-utils looks for an evaluation in an uploaded
    model's folder: ``DIR/<model id>/evaluation-<stamp>/evaluation-simtrace/0-iteration.csv``,
    beside its ``model/model_metadata.json``."""
    stamp = evaluation_stamp(timezone.now())
    metadata = {model.pk: model_metadata(model) for model in models}
    for car in report.cars:
        keys = ModelKeys(str(car.key))
        for key, data in ((keys.evaluation_simtrace(stamp), csv_text(car.rows).encode()),
                          (keys.metadata, metadata[car.key].dumps())):  # fmt: skip
            path = folder / key
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)


def _table(report: RaceReport) -> str:
    lines = [f"{'Pos':<4}{'Model':<28}{'Laps':>5}{'Total':>10}{'Progress':>10}"
             f"{'Off':>5}{'Crash':>6}  Lap times / reason"]  # fmt: skip
    for car in report.cars:
        laps = " ".join(format_lap_s(t) for t in car.lap_times_s)
        note = car.reason if car.status == "out" else laps
        lines.append(
            f"{car.position:<4}{f'{car.name} ({car.key})'[:27]:<28}{car.laps_done:>5}"
            f"{format_lap_s(car.total_time_s):>10}{car.progress:>9.1f}%"
            f"{car.off_track:>5}{car.crashes:>6}  {note}"
        )
    winner = report.winner
    lines.append(f"Winner: {winner.name} ({winner.key})" if winner else "No winner")
    return "\n".join(lines)
