"""`manage.py up`: start the whole console on this machine (see console/launcher.py)."""

from __future__ import annotations

import ipaddress
import os
import sys
from argparse import ArgumentParser
from typing import Any

from django.conf import settings
from django.core.management import call_command
from django.core.management.base import BaseCommand, CommandError
from django.db import connections

from console.launcher import ConsoleOptions, LaunchError, console_run
from training.checks import isolation_summary


class Command(BaseCommand):
    help = (
        "Build the browser assets, migrate the database, then run the web server, Celery beat "
        "and one Celery worker per kind of work (quick tasks, training, evaluation, and "
        "simulation with RACECRAFT_REMOTE_ROLLOUT_SLOTS), with an embedded Redis when "
        "REDIS_URL is unset, until Ctrl-C."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("--host", default="127.0.0.1", help="address to listen on")
        parser.add_argument("--port", type=int, default=8000, help="port to listen on")
        parser.add_argument(
            "--concurrency",
            type=int,
            default=settings.CELERY_WORKER_CONCURRENCY,
            help="training worker processes (default: CELERY_WORKER_CONCURRENCY, 2)",
        )
        parser.add_argument(
            "--evaluation-concurrency",
            type=int,
            default=settings.RACECRAFT_EVALUATION_CONCURRENCY,
            help="evaluation worker processes (default: RACECRAFT_EVALUATION_CONCURRENCY, 1)",
        )

    def handle(
        self,
        *args: Any,
        host: str,
        port: int,
        concurrency: int,
        evaluation_concurrency: int,
        **options: Any,
    ) -> None:
        refuse_debug_on_open_address(host, debug=settings.DEBUG)
        try:
            call_command("build_assets", verbosity=options["verbosity"])
        except CommandError as exc:
            # The console works without the bundle: the reward editor falls back to a plain
            # text box (no highlighting) until Node.js/npm can build it.
            self.stderr.write(f"warning: the code editor could not be built: {exc}")
        call_command("migrate", interactive=False, verbosity=options["verbosity"])
        connections.close_all()
        for line in isolation_summary():  # what protects this machine from reward code
            self.stdout.write(f"racecraft: {line}")
        if settings.DEBUG:
            key_set = bool(os.environ.get("SECRET_KEY", "").strip())
            self.stdout.write(f"racecraft: {debug_mode_note(secret_key_set=key_set)}")
        launch = ConsoleOptions(
            host=host,
            port=port,
            concurrency=concurrency,
            evaluation_concurrency=evaluation_concurrency,
            quick_concurrency=settings.RACECRAFT_QUICK_CONCURRENCY,
            interactive_concurrency=settings.RACECRAFT_INTERACTIVE_CONCURRENCY,
            simulation_slots=settings.RACECRAFT_REMOTE_ROLLOUT_SLOTS,
            job_nice=settings.RACECRAFT_WORKER_NICE,
            redis_url=os.environ.get("REDIS_URL") or None,
            embedded_socket=settings.EMBEDDED_REDIS_SOCKET,
            var_dir=settings.VAR_DIR,
        )
        try:
            console_run(launch, out=sys.stdout)
        except LaunchError as exc:
            raise CommandError(f"racecraft stopped: {exc}") from exc


def refuse_debug_on_open_address(host: str, *, debug: bool) -> None:
    """DEBUG pages show settings and tracebacks to whoever reaches them: with DEBUG on, the
    console listens only on this machine (loopback). Raises CommandError otherwise."""
    if not debug:
        return
    try:
        loopback = ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        loopback = host == "localhost"
    if not loopback:
        raise CommandError(
            f"refusing to listen on {host} with DEBUG on: debug pages show settings and "
            "tracebacks to anyone who can reach them. Set DEBUG=0 (with SECRET_KEY and "
            "ALLOWED_HOSTS) for a console other machines reach, or listen on 127.0.0.1."
        )


def debug_mode_note(*, secret_key_set: bool) -> str:
    """What a console in debug mode (DEBUG unset or 1) is, in one line for `up`'s output."""
    key = "SECRET_KEY" if secret_key_set else "this install's own random key (var/secret_key)"
    return (
        f"debug mode (DEBUG unset or 1): this machine only, cookies signed with {key}. "
        "For a console other machines reach: DEBUG=0 with SECRET_KEY and ALLOWED_HOSTS."
    )
