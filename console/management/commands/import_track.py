"""``manage.py import_track FILE.npy [--id ID] [--name NAME]``: add a DeepRacer track file to
the catalogue, validated first (recorded in the database, so that every machine has it, and
written into RACECRAFT_TRACKS_DIR); the gallery and model forms list it.

DeepRacer's own tracks are built in: one of their files is recognised and refused, naming the
built-in track to pick instead. Track ids are unique without regard to case, and no id (in
any case) of a built-in track is accepted, even with ``--overwrite``."""

from __future__ import annotations

from pathlib import Path

from django.core.management.base import BaseCommand, CommandError, CommandParser

from training import services
from training.errors import ServiceError


class Command(BaseCommand):
    help = "Import a DeepRacer track file (.npy waypoints) into the track catalogue."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("file", help="a DeepRacer .npy track file")
        parser.add_argument("--id", dest="track_id", help="track id (default: the file name)")
        parser.add_argument("--name", default="", help="display name (default: the id)")
        parser.add_argument(
            "--overwrite", action="store_true", help="replace an imported track of that id"
        )

    def handle(self, *args, file: str, track_id: str | None, name: str, overwrite: bool,
               **options) -> None:  # fmt: skip
        path = Path(file)
        if not path.is_file():
            raise CommandError(f"{file}: no such file")
        try:
            info = services.track_add(data=path.read_bytes(), track_id=track_id or path.stem,
                                      name=name, overwrite=overwrite)  # fmt: skip
        except ServiceError as exc:
            raise CommandError(f"{path.name}: {exc}") from None
        self.stdout.write(
            f"imported {info.id!r} ({info.name}): {info.length_m:.2f} m long, "
            f"{info.width_m:.3f} m wide, {info.direction}"
        )
