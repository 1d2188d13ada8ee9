"""``manage.py promote_divisions --month YYYY-MM``: month-end promotion, safe to rerun."""

from __future__ import annotations

from django.core.management.base import BaseCommand, CommandError, CommandParser

from leaderboard import divisions


class Command(BaseCommand):
    help = "Promote the top 10% of a month's Open time-trial racers to Pro for the next month."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "--month", help="the month that ended, YYYY-MM (default: the previous month)"
        )

    def handle(self, *args, month: str | None = None, **options) -> None:
        try:
            target = (
                divisions.parse_month(month)
                if month
                else divisions.previous_month(divisions.month_start())
            )
        except ValueError as exc:
            raise CommandError(str(exc)) from None
        result = divisions.divisions_promote(month=target)
        self.stdout.write(
            f"{target:%Y-%m}: {result.racers} ranked racers, {len(result.promoted)} in the top "
            f"10%, {len(result.newly_promoted)} newly promoted to Pro"
        )
