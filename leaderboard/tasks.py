"""Celery tasks of the league (default queue): month-end promotion and a result safety net.

The beat schedule (console/settings.py, CELERY_BEAT_SCHEDULE) runs ``promote_divisions`` daily
just after midnight UTC for the month that ended (idempotent, so daily runs are harmless and a
missed night is caught up), and ``reconcile_submissions`` every minute (finished submissions,
bracket races and race-day turns whose signal was missed).
"""

from __future__ import annotations

from celery import shared_task

from leaderboard import divisions, racefinish, services


@shared_task(name="leaderboard.tasks.promote_divisions")
def promote_divisions(month: str | None = None) -> dict:
    """Promote the top 10% of ``month`` (``YYYY-MM``; default: the previous month)."""
    target = (
        divisions.parse_month(month) if month else divisions.previous_month(divisions.month_start())
    )
    result = divisions.divisions_promote(month=target)
    return {"month": f"{target:%Y-%m}", "racers": result.racers, "promoted": result.promoted,
            "newly_promoted": result.newly_promoted}  # fmt: skip


@shared_task(name="leaderboard.tasks.reconcile_submissions")
def reconcile_submissions() -> int:
    """Results, bracket matches and race-day turns whose signal was missed."""
    return services.submissions_reconcile() + racefinish.races_reconcile()
