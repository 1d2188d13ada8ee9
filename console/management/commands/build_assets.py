"""`manage.py build_assets`: install the editor's npm packages and bundle them (if stale)."""

from __future__ import annotations

from argparse import ArgumentParser
from typing import Any

from django.core.management.base import BaseCommand, CommandError

from console.assets import AssetBuildError, build_assets, bundle_paths


class Command(BaseCommand):
    help = "npm ci + esbuild: build static/vendor/codemirror.bundle.js when it is missing or stale."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("--force", action="store_true", help="rebuild even when fresh")

    def handle(self, *args: Any, force: bool, **options: Any) -> None:
        try:
            built = build_assets(force=force)
        except AssetBuildError as exc:
            raise CommandError(str(exc)) from exc
        verb = "built" if built else "up to date:"
        self.stdout.write(f"assets {verb} {', '.join(str(p) for p in bundle_paths())}")
