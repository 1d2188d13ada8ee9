"""Racer profiles: an alias chosen once (unique, then fixed), a country and a colour."""

from __future__ import annotations

import re

from django.db import IntegrityError, transaction
from django.utils import timezone

from leaderboard.access import LeagueError
from leaderboard.models import Notification, RacerProfile

ALIAS_RE = re.compile(r"^[A-Za-z0-9_-]{3,32}$")
COLOUR_RE = re.compile(r"^#[0-9a-fA-F]{6}$")


def profile_for(user) -> RacerProfile:
    """The racer's profile, created empty (no alias yet) on first use."""
    profile, _ = RacerProfile.objects.get_or_create(user=user)
    return profile


def profile_update(
    *, user, alias: str | None = None, country: str = "", colour: str = "#ff9f1c"
) -> RacerProfile:
    """Set country and colour; set the alias only when the racer has none yet.

    Raises LeagueError when the alias is malformed, taken, or differs from a fixed alias.
    """
    country = (country or "").strip().upper()
    if country and not re.fullmatch(r"[A-Z]{2}", country):
        raise LeagueError("a country is a two-letter code such as DE or BR", field="country")
    if not COLOUR_RE.fullmatch(colour or ""):
        raise LeagueError("a colour looks like #ff9f1c", field="colour")
    with transaction.atomic():
        profile = RacerProfile.objects.select_for_update().get(pk=profile_for(user).pk)
        alias = (alias or "").strip()
        if profile.alias and alias and alias != profile.alias:
            raise LeagueError("your racer alias is fixed once chosen", field="alias")
        if not profile.alias and alias:
            if not ALIAS_RE.fullmatch(alias):
                raise LeagueError(
                    "an alias is 3-32 letters, digits, hyphens or underscores", field="alias"
                )
            if RacerProfile.objects.filter(alias__iexact=alias).exclude(pk=profile.pk).exists():
                raise LeagueError(f"the alias {alias!r} is taken", field="alias")
            profile.alias = alias
        profile.country = country
        profile.colour = colour.lower()
        try:
            with transaction.atomic():
                profile.save()
        except IntegrityError:
            raise LeagueError(f"the alias {alias!r} is taken", field="alias") from None
    return profile


def notifications_mark_read(*, user) -> int:
    """Mark the racer's notifications read (they stay listed, no longer highlighted)."""
    return Notification.objects.filter(user=user, read_at__isnull=True).update(
        read_at=timezone.now()
    )
