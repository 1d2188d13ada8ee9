"""Divisions: everyone starts in Open; a top-10% month in Open time trials promotes to Pro.

A racer's division in a month is their :class:`DivisionMembership` for that month, else their
latest earlier one (Pro stays Pro), else Open. Months are calendar months in UTC.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from datetime import UTC, date, datetime
from fractions import Fraction

from django.db import transaction
from django.urls import reverse
from django.utils import timezone

from leaderboard.models import (
    Division,
    DivisionMembership,
    Notification,
    Submission,
)
from training.models import RaceType

PROMOTION_SHARE = Fraction(1, 10)


def month_start(moment: datetime | date | None = None) -> date:
    """The first day of the (UTC) month of ``moment`` (default: now)."""
    if moment is None:
        moment = timezone.now()
    if isinstance(moment, datetime):
        moment = moment.astimezone(UTC).date()
    return moment.replace(day=1)


def next_month(month: date) -> date:
    return date(month.year + (month.month == 12), month.month % 12 + 1, 1)


def previous_month(month: date) -> date:
    return date(month.year - (month.month == 1), (month.month - 2) % 12 + 1, 1)


def parse_month(text: str) -> date:
    """``YYYY-MM`` → the first day of that month; ValueError otherwise."""
    try:
        return datetime.strptime(text, "%Y-%m").date()
    except ValueError:
        raise ValueError(f"{text!r} is not a month like 2025-03") from None


def division_for(user, at: datetime | date | None = None) -> str:
    """The racer's division (``Division`` value) in the month of ``at`` (default: now)."""
    month = month_start(at)
    membership = (
        DivisionMembership.objects.filter(racer=user, month__lte=month).order_by("-month").first()
    )
    return membership.division if membership else Division.OPEN


def _month_bounds(month: date) -> tuple[datetime, datetime]:
    start = datetime(month.year, month.month, 1, tzinfo=UTC)
    end_day = next_month(month)
    return start, datetime(end_day.year, end_day.month, 1, tzinfo=UTC)


def monthly_standings(month: date) -> dict[int, Fraction]:
    """Each racer's best standing in ``month``'s Open time trials.

    The results that count are RANKED submissions created during the month (UTC) to public,
    Open-division, time-trial events. Within each event every racer keeps their best score;
    the racer's standing there is ``(1 + racers with a strictly lower score) / racers ranked``
    (equal times share a standing). A racer's month standing is their best (lowest) standing
    over the events they raced: a fraction in (0, 1], lower is better. Lap times are never
    compared across events, whose tracks differ.
    """
    start, end = _month_bounds(month)
    rows = Submission.objects.filter(
        status=Submission.Status.RANKED,
        created_at__gte=start,
        created_at__lt=end,
        event__is_private=False,
        event__division=Division.OPEN,
        event__race_type=RaceType.TIME_TRIAL,
    ).values_list("event_id", "racer_id", "score_ms")
    per_event: dict[int, dict[int, int]] = defaultdict(dict)
    for event_id, racer_id, score in rows:
        best = per_event[event_id].get(racer_id)
        if best is None or score < best:
            per_event[event_id][racer_id] = score
    standings: dict[int, Fraction] = {}
    for scores in per_event.values():
        ordered = sorted(scores.values())
        for racer_id, score in scores.items():
            better = sum(1 for s in ordered if s < score)
            standing = Fraction(1 + better, len(ordered))
            if racer_id not in standings or standing < standings[racer_id]:
                standings[racer_id] = standing
    return standings


def promotion_winners(standings: dict[int, Fraction]) -> set[int]:
    """The top 10% of racers by standing: ``k = max(1, ceil(n / 10))`` racers, plus everyone
    tied with the k-th. No racers, no winners."""
    if not standings:
        return set()
    ordered = sorted(standings.values())
    k = max(1, math.ceil(len(ordered) * PROMOTION_SHARE))
    line = ordered[k - 1]
    return {racer for racer, standing in standings.items() if standing <= line}


@dataclass(frozen=True)
class PromotionResult:
    month: date
    racers: int
    promoted: list[int]
    newly_promoted: list[int]


def divisions_promote(*, month: date) -> PromotionResult:
    """Promote ``month``'s top 10% of Open time-trial racers to Pro for the next month.

    Idempotent: a racer already Pro next month is left alone, and a racer is told once (the
    notification comes with the membership row, both in one transaction).
    """
    month = month_start(month)
    target = next_month(month)
    standings = monthly_standings(month)
    winners = sorted(promotion_winners(standings))
    newly: list[int] = []
    link = reverse("league")
    with transaction.atomic():
        for racer_id in winners:
            membership, created = DivisionMembership.objects.get_or_create(
                racer_id=racer_id,
                month=target,
                defaults={
                    "division": Division.PRO,
                    "reason": f"top 10% of Open time trials in {month:%Y-%m}",
                },
            )
            if not created and membership.division == Division.PRO:
                continue
            if not created:
                membership.division = Division.PRO
                membership.save(update_fields=["division"])
            newly.append(racer_id)
            Notification.objects.create(
                user_id=racer_id,
                link=link,
                message=(
                    f"Congratulations! Your {month:%B %Y} time trials put you in the top 10%: "
                    f"you race in the Pro division from {target:%B %Y}."
                ),
            )
    return PromotionResult(month, len(standings), winners, newly)
