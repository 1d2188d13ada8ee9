"""`manage.py racecraft_import`: a model from a virtual-model archive, or straight from a
DeepRacer-for-Cloud bucket (``--from-bucket``)."""

from __future__ import annotations

import getpass
import os
import sys
from argparse import ArgumentParser
from typing import Any

from django.core.management.base import BaseCommand, CommandError
from django.views.decorators.debug import sensitive_variables

from training import services
from training.management.cli import (
    action_summary,
    add_owner_argument,
    elapsed_ticker,
    service_errors,
)
from training.selectors import user_by_username

KEY_VARIABLES = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY")
"""Where ``--from-bucket`` reads the keys (as DeepRacer-for-Cloud's own tools do); never from
an argument, which other users of the machine can read in the process list."""


class Command(BaseCommand):
    help = (
        "Import a virtual model (.tar.gz or .zip, as racecraft_export --virtual or the console "
        "writes it, or a DeepRacer model folder archived) as a new model of --owner, or, with "
        "--from-bucket ENDPOINT BUCKET PREFIX, a DeepRacer-for-Cloud model straight from its "
        "MinIO or S3 bucket (keys from AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, else asked "
        "for; never stored). Prints the new model's id (only the id with -v 0)."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument(
            "archive", metavar="ARCHIVE", nargs="?", help="the archive (not with --from-bucket)"
        )
        parser.add_argument(
            "--from-bucket",
            nargs=3,
            metavar=("ENDPOINT", "BUCKET", "PREFIX"),
            help="read the model from a DeepRacer-for-Cloud bucket: the S3 endpoint "
            "(host:port, e.g. localhost:9000), the bucket and the model's prefix "
            "(e.g. rl-deepracer-sagemaker; '' for the bucket's top). Only public addresses "
            "are reached unless RACECRAFT_OUTBOUND_ALLOW names the host or its network "
            "(e.g. RACECRAFT_OUTBOUND_ALLOW=localhost for a DeepRacer-for-Cloud on this machine)",
        )
        parser.add_argument(
            "--https", action="store_true", help="talk HTTPS to the endpoint (or give https://)"
        )
        parser.add_argument("--region", default="", help="the bucket's region, when it needs one")
        add_owner_argument(parser, required=True)
        parser.add_argument("--name", required=True, help="1-64 letters, digits or hyphens")
        parser.add_argument("--description", default="", help="at most 255 characters")

    def handle(self, *args: Any, archive: str | None, **options: Any) -> None:
        if (archive is None) == (options["from_bucket"] is None):
            raise CommandError("give either ARCHIVE or --from-bucket ENDPOINT BUCKET PREFIX")
        with service_errors():
            owner = user_by_username(username=options["owner"])
        if archive is None:
            model = self._from_bucket(owner, *options["from_bucket"], options)
        else:
            model = self._from_archive(owner, archive, options)
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

    def _from_archive(self, owner: Any, archive: str, options: dict[str, Any]) -> Any:
        try:
            upload = open(archive, "rb")  # noqa: SIM115 - closed below
        except OSError as exc:
            raise CommandError(f"cannot read {archive}: {exc.strerror or exc}") from None
        ticker = elapsed_ticker(
            self.stdout if options["verbosity"] else None,
            f"Importing {archive}: reading the archive and checking its checkpoint",
        )
        with upload, service_errors(f"cannot import {archive}"), ticker:
            return services.model_import(
                owner=owner,
                name=options["name"],
                upload=upload,
                description=options["description"],
            )

    @sensitive_variables()
    def _from_bucket(
        self, owner: Any, endpoint: str, bucket: str, prefix: str, options: dict[str, Any]
    ) -> Any:
        access_key, secret_key = _bucket_keys()
        where = f"s3://{bucket}/{prefix.strip('/')}".rstrip("/")
        ticker = elapsed_ticker(
            self.stdout if options["verbosity"] else None,
            f"Importing {where} from {endpoint}: reading the model and checking its checkpoint",
        )
        with service_errors(f"cannot import {where}"), ticker:
            return services.model_import_from_bucket(
                owner=owner,
                name=options["name"],
                endpoint=endpoint,
                bucket=bucket,
                prefix=prefix,
                access_key=access_key,
                secret_key=secret_key,
                secure=options["https"],
                region=options["region"],
                description=options["description"],
            )


@sensitive_variables()
def _bucket_keys() -> tuple[str, str]:
    """The keys from :data:`KEY_VARIABLES`, else asked for on the terminal (the secret without
    echo). Raises :class:`CommandError` when neither is possible."""
    access_key, secret_key = (os.environ.get(name, "") for name in KEY_VARIABLES)
    if access_key and secret_key:
        return access_key, secret_key
    if not sys.stdin.isatty():
        raise CommandError(
            f"--from-bucket needs the keys: set {' and '.join(KEY_VARIABLES)} "
            "(they are never taken from an argument)"
        )
    try:
        access_key = access_key or input("Access key: ").strip()
        secret_key = secret_key or getpass.getpass("Secret key: ")
    except (EOFError, KeyboardInterrupt):
        raise CommandError("no keys given") from None
    return access_key, secret_key
