"""`manage.py racecraft_import`: a model from a virtual-model archive."""

from __future__ import annotations

from argparse import ArgumentParser
from typing import Any

from django.core.management.base import BaseCommand, CommandError

from training import services
from training.management.cli import (
    action_summary,
    add_owner_argument,
    elapsed_ticker,
    service_errors,
)
from training.selectors import user_by_username


class Command(BaseCommand):
    help = (
        "Import a virtual model (.tar.gz or .zip, as racecraft_export --virtual or the console "
        "writes it, or a DeepRacer model folder archived) as a new model of --owner. Prints "
        "the new model's id (only the id with -v 0)."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("archive", metavar="ARCHIVE", help="the archive file")
        add_owner_argument(parser, required=True)
        parser.add_argument("--name", required=True, help="1-64 letters, digits or hyphens")
        parser.add_argument("--description", default="", help="at most 255 characters")

    def handle(self, *args: Any, archive: str, **options: Any) -> None:
        with service_errors():
            owner = user_by_username(username=options["owner"])
        try:
            upload = open(archive, "rb")  # noqa: SIM115 - closed below
        except OSError as exc:
            raise CommandError(f"cannot read {archive}: {exc.strerror or exc}") from None
        ticker = elapsed_ticker(
            self.stdout if options["verbosity"] else None,
            f"Importing {archive}: reading the archive and checking its checkpoint",
        )
        with upload, service_errors(f"cannot import {archive}"), ticker:
            model = services.model_import(
                owner=owner,
                name=options["name"],
                upload=upload,
                description=options["description"],
            )
        if options["verbosity"] == 0:
            self.stdout.write(str(model.pk))
            return
        self.stdout.write(
            f"Imported model {model.pk}: {model.name} ({model.algorithm}, {action_summary(model)}, "
            f"{', '.join(model.sensors)}) on {model.track_id} ({model.direction}), "
            f"seed {model.seed}"
        )
        if model.import_note:
            self.stderr.write(f"Note: {model.import_note}")
