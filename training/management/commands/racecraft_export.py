"""`manage.py racecraft_export`: write a model's archives (car, virtual model, logs)."""

from __future__ import annotations

from argparse import ArgumentParser
from collections.abc import Callable
from pathlib import Path
from typing import Any

from django.core.management.base import BaseCommand, CommandError

from training.management.cli import add_model_arguments, owner_and_model, service_errors
from training.models import RacingModel
from training.services import downloads

ARCHIVES: dict[str, tuple[Callable[[RacingModel], bytes], str, str]] = {
    "car": (downloads.car_model_archive, "physicalmodel-{name}.tar.gz", "car model"),
    "onnx": (downloads.onnx_policy, "{name}-policy.onnx", "ONNX policy"),
    "virtual": (downloads.virtual_model_archive, "virtualmodel-{name}.tar.gz", "virtual model"),
    "logs": (downloads.logs_archive, "{name}-logs.tar.gz", "logs"),
}
"""What can be exported: the builder, the file name in a folder, and what to call it."""


class Command(BaseCommand):
    help = (
        "Write a model's archives, as the console's downloads: --car (agent/model.pb + "
        "model_metadata.json, for the physical car), --onnx (the policy as ONNX, for other "
        "runtimes), --virtual (the whole model, re-importable with "
        "racecraft_import), --logs (sim-traces and metrics). A PATH that is a folder gets "
        "the console's file name."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        add_model_arguments(parser)
        for kind, (_, filename, what) in ARCHIVES.items():
            parser.add_argument(
                f"--{kind}",
                metavar="PATH",
                help=f"write the {what} archive here (in a folder: {filename})",
            )

    def handle(self, *args: Any, model_id: int, owner: str | None, **options: Any) -> None:
        wanted = {kind: options[kind] for kind in ARCHIVES if options[kind]}
        if not wanted:
            choices = ", ".join(f"--{kind} PATH" for kind in ARCHIVES)
            raise CommandError(f"say what to export: {choices}")
        _, model = owner_and_model(model_id, owner)
        for kind, target in wanted.items():
            build, filename, what = ARCHIVES[kind]
            with service_errors(f"the {what} archive"):
                data = build(model)
            path = Path(target)
            if path.is_dir():
                path = path / filename.format(name=model.name)
            try:
                path.write_bytes(data)
            except OSError as exc:
                raise CommandError(f"cannot write {path}: {exc.strerror or exc}") from None
            self.stdout.write(f"Wrote the {what} archive: {path} ({len(data):,} bytes)")
