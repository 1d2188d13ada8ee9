"""Who may do what in the league: roles, event visibility and management, and the one error.

Racers enter events; race facilitators (the "Race facilitators" group, and staff) create and
run public events and see every submission; an event's organiser runs their own event.
"""

from __future__ import annotations

from django.contrib.auth.models import AbstractBaseUser, AnonymousUser

from leaderboard.models import FACILITATORS_GROUP, Event, EventEntrant

User = AbstractBaseUser | AnonymousUser


class LeagueError(Exception):
    """A request we refuse, in words the racer can act on; ``field`` names a form field."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field


def is_facilitator(user: User) -> bool:
    if not user.is_authenticated:
        return False
    if user.is_staff or user.is_superuser:
        return True
    return user.groups.filter(name=FACILITATORS_GROUP).exists()


def can_manage_event(user: User, event: Event) -> bool:
    """The organiser, and facilitators for every event."""
    if not user.is_authenticated:
        return False
    return event.organiser_id == user.pk or is_facilitator(user)


def is_entrant(user: User, event: Event) -> bool:
    """Admitted to a private event (through its link) and not removed since."""
    if not user.is_authenticated:
        return False
    return EventEntrant.objects.filter(event=event, racer=user, removed_at__isnull=True).exists()


def can_view_event(user: User, event: Event) -> bool:
    """Public events: everyone (Open racers may watch Pro leaderboards and vice versa).
    Private events: the organiser, facilitators and current entrants."""
    if not event.is_private:
        return True
    return can_manage_event(user, event) or is_entrant(user, event)
