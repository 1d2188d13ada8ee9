"""Events: create, edit, close early; community races' invite links and participants; who may
enter. Every function is keyword-only and raises :class:`LeagueError` with a clear message."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from django.db import transaction
from django.utils import timezone

from leaderboard.access import LeagueError, can_manage_event, is_entrant, is_facilitator
from leaderboard.divisions import division_for
from leaderboard.models import Division, Event, EventEntrant, RankingMethod, new_invite_token
from training.models import RaceType
from training.services import ServiceError, check_track, race_settings
from training.services.conditions import conditions_check

EVENT_FIELDS = (
    "season", "name", "description", "track_id", "direction", "race_type", "number_of_objects",
    "randomize_objects", "bot_count", "bot_speed_mps", "bot_lane_changes", "opens_at",
    "closes_at", "division", "ranking_method", "min_laps", "max_laps", "off_track_penalty_s",
    "collision_penalty_s", "max_resets", "max_submissions_per_racer", "bracket_size",
    "bracket_laps", "bracket_on_race_day", "conditions", "conditions_seed",
    "live_speed_control",
)  # fmt: skip
RULE_FIELDS = (
    "track_id", "direction", "race_type", "ranking_method", "min_laps", "max_laps",
    "off_track_penalty_s", "collision_penalty_s", "max_resets", "number_of_objects",
    "randomize_objects", "bot_count", "bot_speed_mps", "bot_lane_changes", "conditions",
    "conditions_seed",
)  # fmt: skip
"""What decides a score: fixed once the first submission is in."""


RACE_FIELDS = {
    "number_of_objects": "number_of_objects",
    "object_positions": "number_of_objects",
    "number_of_bots": "bot_count",
    "bot_speed": "bot_speed_mps",
    "lane_change_min_s": "bot_lane_changes",
}
"""Where the race rules' complaints go on an event's form."""


def event_race(event: Event) -> dict[str, Any]:
    """The event's race settings as an evaluation takes them (``race_config``): {} for a time
    trial, the boxes of an object-avoidance race or the bots of a head-to-bot race, checked by
    the race rules (:func:`training.services.race_settings`). Raises :class:`LeagueError`."""
    settings: dict[str, Any] = {}
    if event.race_type == RaceType.OBJECT_AVOIDANCE:
        settings = {"number_of_objects": event.number_of_objects,
                    "randomize_objects": event.randomize_objects}  # fmt: skip
    elif event.race_type == RaceType.HEAD_TO_BOT:
        settings = {"number_of_bots": event.bot_count, "bot_speed": event.bot_speed_mps,
                    "bot_lane_change": event.bot_lane_changes}  # fmt: skip
    try:
        return race_settings(event.race_type, settings)
    except ServiceError as exc:
        field = RACE_FIELDS.get(exc.field or "", "race_type")
        raise LeagueError(exc.message, field=field) from None


def _check_event(event: Event) -> None:
    if not event.name.strip():
        raise LeagueError("give the event a name", field="name")
    try:
        check_track(event.track_id, event.direction)
    except ServiceError as exc:
        raise LeagueError(exc.message, field=exc.field) from None
    if event.race_type not in RaceType.values:
        raise LeagueError("unknown race type", field="race_type")
    event_race(event)
    if event.ranking_method not in RankingMethod.values:
        raise LeagueError("unknown ranking method", field="ranking_method")
    if not 1 <= event.min_laps <= event.max_laps <= 5:
        raise LeagueError(
            "laps: 1 ≤ minimum ≤ maximum ≤ 5 (the evaluation runs the maximum, at least 3)",
            field="min_laps",
        )
    if event.opens_at >= event.closes_at:
        raise LeagueError("the event must open before it closes", field="closes_at")
    for name in ("off_track_penalty_s", "collision_penalty_s"):
        if not 0 <= getattr(event, name) <= 60:
            raise LeagueError("penalties are 0-60 seconds", field=name)
    if not 1 <= event.max_submissions_per_racer <= 999:
        raise LeagueError("allow 1-999 submissions per racer", field="max_submissions_per_racer")
    if event.division not in Division.values:
        raise LeagueError("unknown division", field="division")
    if event.bracket_size not in (0, 4, 8, 16, 32):
        raise LeagueError("a bracket takes the top 4, 8, 16 or 32", field="bracket_size")
    if not 1 <= event.bracket_laps <= 10:
        raise LeagueError("a bracket race runs 1 to 10 laps", field="bracket_laps")
    try:  # the outside world: {} (clean) unless the event says otherwise
        event.conditions = conditions_check(event.conditions)
    except ServiceError as exc:
        raise LeagueError(exc.message, field="conditions") from None
    if not 0 <= (event.conditions_seed or 0) < 2**31:
        raise LeagueError("the conditions' seed is 0 to 2147483647", field="conditions_seed")


def event_create(*, organiser, is_private: bool, **fields: Any) -> Event:
    """A public event (facilitators only) or a private community race (any racer).

    ``fields`` are among :data:`EVENT_FIELDS`. A community race is Open-division and has no
    season: the division rule does not apply to private events.
    """
    if not organiser.is_authenticated:
        raise LeagueError("sign in to organise a race")
    if not is_private and not is_facilitator(organiser):
        raise LeagueError("only race facilitators create public league events")
    unknown = set(fields) - set(EVENT_FIELDS)
    if unknown:
        raise TypeError(f"unknown event fields: {sorted(unknown)}")
    if is_private:
        fields.update(season=None, division=Division.OPEN)
    event = Event(organiser=organiser, is_private=is_private, **fields)
    _check_event(event)
    with transaction.atomic():
        event.save()
        if is_private:
            EventEntrant.objects.create(event=event, racer=organiser)
    return event


def event_update(*, event: Event, user, **fields: Any) -> Event:
    """Edit an event (organiser or facilitator); scoring rules are fixed after the first
    submission. A community race stays private."""
    if not can_manage_event(user, event):
        raise LeagueError("only the organiser or a race facilitator can edit this event")
    unknown = set(fields) - set(EVENT_FIELDS)
    if unknown:
        raise TypeError(f"unknown event fields: {sorted(unknown)}")
    if event.is_private:
        fields.pop("season", None)
        fields.pop("division", None)
    with transaction.atomic():
        event = Event.objects.select_for_update(no_key=True).get(pk=event.pk)
        changed = [name for name, value in fields.items() if getattr(event, name) != value]
        if event.submissions.exists() and set(changed) & set(RULE_FIELDS):
            raise LeagueError(
                "racers have already submitted: the track and scoring rules can no longer "
                "change (names, description, dates and limits still can)"
            )
        for name, value in fields.items():
            setattr(event, name, value)
        _check_event(event)
        event.save()
    return event


def event_close(*, event: Event, user, now: datetime | None = None) -> Event:
    """Close an event now (its invite link dies with it). Running submissions still finish."""
    if not can_manage_event(user, event):
        raise LeagueError("only the organiser or a race facilitator can close this event")
    now = now or timezone.now()
    if event.is_closed(now):
        raise LeagueError("this event is already closed")
    event.closes_at = max(now, event.opens_at + timezone.timedelta(microseconds=1))
    event.save(update_fields=["closes_at"])
    return event


def event_invite_reset(*, event: Event, user) -> Event:
    """A new invite token: the old link stops working; entrants stay."""
    if not event.is_private:
        raise LeagueError("only community races have invite links")
    if not can_manage_event(user, event):
        raise LeagueError("only the organiser can reset the invite link")
    event.invite_token = new_invite_token()
    event.save(update_fields=["invite_token"])
    return event


def event_for_invite(*, token: str, now: datetime | None = None) -> Event:
    """The private event behind an invite token, while it is open for joining."""
    event = Event.objects.filter(invite_token=token, is_private=True).first()
    if event is None:
        raise LeagueError("this invite link is not valid (the organiser may have reset it)")
    if event.is_closed(now):
        raise LeagueError("this race has closed: its invite link has expired")
    return event


def event_join(*, token: str, user, now: datetime | None = None) -> Event:
    """Admit a racer to a community race through its invite link."""
    if not user.is_authenticated:
        raise LeagueError("sign in to join this race")
    event = event_for_invite(token=token, now=now)
    entrant, _ = EventEntrant.objects.get_or_create(event=event, racer=user)
    if entrant.removed_at is not None:
        raise LeagueError("the organiser removed you from this race")
    return event


def event_participant_remove(*, event: Event, user, racer) -> None:
    """Remove a racer from a community race: they leave its leaderboard and cannot rejoin."""
    if not event.is_private:
        raise LeagueError("participants are removed from community races only")
    if not can_manage_event(user, event):
        raise LeagueError("only the organiser can remove participants")
    if racer.pk == event.organiser_id:
        raise LeagueError("the organiser cannot be removed from their own race")
    updated = EventEntrant.objects.filter(event=event, racer=racer, removed_at__isnull=True).update(
        removed_at=timezone.now()
    )
    if not updated:
        raise LeagueError("this racer is not in the race")


def event_entry_check(*, event: Event, user, now: datetime | None = None) -> None:
    """Raise LeagueError unless ``user`` may submit to ``event`` right now."""
    now = now or timezone.now()
    if not user.is_authenticated:
        raise LeagueError("sign in to enter a race")
    if now < event.opens_at:
        raise LeagueError(f"this event opens on {event.opens_at:%Y-%m-%d %H:%M} UTC")
    if event.is_closed(now):
        raise LeagueError("this event has closed: no more submissions")
    if event.is_private:
        if not (is_entrant(user, event) or event.organiser_id == user.pk):
            raise LeagueError("this is a private race: open its invite link to join first")
        return
    division = division_for(user, now)
    if division != event.division:
        raise LeagueError(
            f"this is a {Division(event.division).label} division event and you race in "
            f"{Division(division).label} this month"
        )
