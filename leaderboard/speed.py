"""Live speed control on race day, as DeepRacer's LIVE races ran it: during their turn, a racer
sets their car's speed multiplier (0.5×-1.5× in steps of 0.05) from a phone; the car drives
its model's actions at that multiplier from the next step, the broadcast shows it and the car's
sim-trace records it each step.

Who may: only when the event has ``live_speed_control`` on, only while a race-day turn is on
track, and only its racer (the entrant of the turn's solo run, or of one side of its bracket
match), for their own car. The value goes to the race through training's service
(:func:`training.services.race_control.race_speed_set`): the league never writes a race job.
"""

from __future__ import annotations

from dataclasses import dataclass

from leaderboard.access import LeagueError
from leaderboard.models import Event, RaceDaySlot, Submission
from training.errors import ServiceError
from training.models import RaceJob
from training.services.race_control import (
    MAX_SPEED_MULTIPLIER,
    MIN_SPEED_MULTIPLIER,
    race_speed_applied,
    race_speed_of,
    race_speed_set,
)

__all__ = [
    "MAX_SPEED_MULTIPLIER",
    "MIN_SPEED_MULTIPLIER",
    "LiveTurn",
    "SpeedRefused",
    "live_turn_of",
    "race_speed_change",
]


class SpeedRefused(LeagueError):
    """Not this user's to change now (the setting is off, it is not their turn, or the car is
    not theirs): a 403, with the sentence."""


@dataclass(frozen=True)
class LiveTurn:
    """The racer's car on track: the turn, its race job, the car's entry index in the race
    and its entry; ``speed`` the multiplier as last set (1.0 until changed); ``driving`` what
    the car drives at now, as the race reported it (None before it drives)."""

    slot: RaceDaySlot
    race: RaceJob
    index: int
    submission: Submission
    speed: float
    driving: float | None


def live_turn_of(*, event: Event, user) -> LiveTurn:
    """The user's car on track in ``event``'s race day. Raises :class:`SpeedRefused` with a
    sentence when the event has no live speed control, no turn is on track, or the turn on
    track is someone else's."""
    if not event.live_speed_control:
        raise SpeedRefused("live speed control is off for this event")
    if not getattr(user, "is_authenticated", False):
        raise SpeedRefused("sign in as the racer whose turn it is")
    slot = (
        RaceDaySlot.objects.filter(event=event, status=RaceDaySlot.Status.RUNNING)
        .select_related("race", "submission", "match__top", "match__bottom")
        .first()
    )
    if slot is None or slot.race is None:
        raise SpeedRefused("no race is on track: you can change your speed only during your turn")
    subs = [slot.submission] if slot.submission_id else [slot.match.top, slot.match.bottom]
    mine = [sub for sub in subs if sub is not None and sub.racer_id == user.pk]
    if not mine:
        raise SpeedRefused("it is not your turn: only the racer on track changes their speed")
    tags = [entry.get("tag") for entry in slot.race.entries]
    sub = mine[0]
    if sub.pk not in tags:
        raise SpeedRefused("your car is not in the race on track")
    index = tags.index(sub.pk)
    race_id = slot.race.pk
    return LiveTurn(
        slot, slot.race, index, sub, race_speed_of(race_id, index),
        race_speed_applied(race_id, index),
    )  # fmt: skip


def race_speed_change(*, event: Event, user, multiplier: object) -> float:
    """Set the user's car's speed multiplier in their turn on track; returns the value set.
    Raises :class:`SpeedRefused` (see :func:`live_turn_of`) or :class:`LeagueError` for a
    bad value (0.5-1.5 in steps of 0.05) or a race that ended meanwhile."""
    turn = live_turn_of(event=event, user=user)
    try:
        return race_speed_set(race=turn.race, index=turn.index, multiplier=multiplier)
    except ServiceError as exc:
        raise LeagueError(exc.message) from None
