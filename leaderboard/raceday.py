"""A live race day, as DeepRacer's LIVE races and DREM ran physical events: the facilitator
orders a queue of turns (a racer's solo run, or a bracket match), launches the next, skips,
pauses; the racer is told when they are up next; every turn is a race job paced at real time
whose frames go to the event's broadcast page (:func:`leaderboard.live.broadcast_group`).

Only the event's organiser and race facilitators run a race day (:func:`can_manage_event`).
One turn is on track at a time; a turn whose race ends (finished, failed or stopped) is done
and the queue moves on, so it is never left stuck (the league's one ``race_finished`` handler,
:mod:`leaderboard.racefinish`, calls :func:`race_day_race_finished`). A bracket match raced as
a turn comes from :mod:`leaderboard.bracket`, which never imports this module. With the event's
live speed control on, the racer on track sets their car's speed (:mod:`leaderboard.speed`).
"""

from __future__ import annotations

import secrets

from django.db import transaction
from django.db.models import Max
from django.urls import reverse

from leaderboard.access import LeagueError, can_manage_event
from leaderboard.bracket import match_race
from leaderboard.eventraces import entry_race
from leaderboard.live import (
    broadcast_access_changed,
    broadcast_group,
    race_day_changed,
    race_standings,
)
from leaderboard.models import Event, Notification, RaceDaySlot, Submission
from training.models import FINISHED_JOB_STATUSES, JobStatus, RaceJob
from training.services.race_control import race_stop

Slot = RaceDaySlot


def _check(event: Event, user) -> None:
    if not can_manage_event(user, event):
        raise LeagueError("only the event's organiser or a race facilitator runs its race day")


def race_day_add(*, event: Event, user, submission: Submission) -> RaceDaySlot:
    """Put a racer's entry (a ranked or unranked submission of this event) at the end."""
    _check(event, user)
    if submission.event_id != event.pk:
        raise LeagueError("that entry belongs to another event")
    with transaction.atomic():
        Event.objects.select_for_update(no_key=True).get(pk=event.pk)
        last = RaceDaySlot.objects.filter(event=event).aggregate(m=Max("position"))["m"] or 0
        slot = RaceDaySlot.objects.create(event=event, submission=submission, position=last + 1)
        _notify_next(event)
    race_day_changed(event.pk, {"queue": True})
    return slot


def race_day_move(*, slot: RaceDaySlot, user, up: bool) -> None:
    """Swap a waiting turn with the waiting turn before (``up``) or after it."""
    _check(slot.event, user)
    with transaction.atomic():
        Event.objects.select_for_update(no_key=True).get(pk=slot.event_id)
        waiting = list(RaceDaySlot.objects.filter(event_id=slot.event_id,
                                                  status=RaceDaySlot.Status.WAITING))  # fmt: skip
        index = next((i for i, s in enumerate(waiting) if s.pk == slot.pk), None)
        if index is None:
            raise LeagueError("only a waiting turn can move")
        other = index - 1 if up else index + 1
        if not 0 <= other < len(waiting):
            return
        a, b = waiting[index], waiting[other]
        a.position, b.position = b.position, a.position
        RaceDaySlot.objects.filter(pk=a.pk).update(position=a.position)
        RaceDaySlot.objects.filter(pk=b.pk).update(position=b.position)
        _notify_next(slot.event)
    race_day_changed(slot.event_id, {"queue": True})


def race_day_skip(*, slot: RaceDaySlot, user) -> None:
    _check(slot.event, user)
    changed = RaceDaySlot.objects.filter(pk=slot.pk, status=RaceDaySlot.Status.WAITING).update(
        status=RaceDaySlot.Status.SKIPPED
    )
    if not changed:
        raise LeagueError("only a waiting turn can be skipped")
    _notify_next(slot.event)
    race_day_changed(slot.event_id, {"queue": True})


def race_day_pause(*, event: Event, user, paused: bool) -> None:
    """Hold the queue (no turn can be launched) or let it go again."""
    _check(event, user)
    Event.objects.filter(pk=event.pk).update(race_day_paused=paused)
    event.race_day_paused = paused
    race_day_changed(event.pk, {"queue": True, "paused": paused})


def race_day_launch(*, event: Event, user) -> RaceDaySlot:
    """Put the next waiting turn on track: a race job paced at real time, broadcast. A
    community race's turn counts against its organiser's job quota: when it is full this
    raises :class:`~leaderboard.eventraces.LeagueQuotaError` and the turn stays first in the
    queue (nothing is started, nothing is lost)."""
    _check(event, user)
    with transaction.atomic():
        # NO KEY: a submission written to this event meanwhile (it holds its racer's row,
        # which the quota below locks too) must not wait on this lock: no deadlock.
        event = Event.objects.select_for_update(no_key=True).get(pk=event.pk)
        if event.race_day_paused:
            raise LeagueError("the race day is paused; resume it to launch the next turn")
        if RaceDaySlot.objects.filter(event=event, status=RaceDaySlot.Status.RUNNING).exists():
            raise LeagueError("a race is on track; wait for it to finish")
        waiting = RaceDaySlot.objects.filter(event=event, status=RaceDaySlot.Status.WAITING)
        slot = waiting.select_related("match").first()
        while slot is not None and slot.match_id and slot.match.winner_id is not None:
            # A match decided while it waited (its opponent withdrew): nothing to race.
            RaceDaySlot.objects.filter(pk=slot.pk).update(status=RaceDaySlot.Status.DONE)
            slot = waiting.select_related("match").first()
        if slot is None:
            raise LeagueError("the queue is empty")
        group = broadcast_group(event.pk)
        if slot.match_id is not None:
            race = match_race(event, slot.match, paced=True, broadcast_group=group)
            slot.match.race, slot.match.attempts = race, slot.match.attempts + 1
            slot.match.save(update_fields=["race", "attempts"])
        else:
            race = entry_race(event, [slot.submission], laps=event.max_laps,
                              title=f"{event.name}: {slot.submission.model_name}",
                              paced=True, broadcast_group=group)  # fmt: skip
        slot.race, slot.status = race, RaceDaySlot.Status.RUNNING
        slot.save(update_fields=["race", "status"])
        _notify_next(event)
        race_id, title = race.pk, race.title
        transaction.on_commit(lambda: race_day_changed(
            event.pk, {"race": race_id, "title": title, "started": True}))  # fmt: skip
    return slot


def race_day_race_finished(*, race_id: int) -> RaceDaySlot | None:
    """The race of a turn ended: the turn is done and the broadcast page shows the winner."""
    slot = RaceDaySlot.objects.filter(race_id=race_id, status=RaceDaySlot.Status.RUNNING).first()
    if slot is None:
        return None
    race = RaceJob.objects.get(pk=race_id)
    if race.status not in FINISHED_JOB_STATUSES:
        return None
    RaceDaySlot.objects.filter(pk=slot.pk).update(status=RaceDaySlot.Status.DONE)
    winner = next((car for car in race.car_rows if car.get("model") == race.results.get("winner")),
                  None)  # fmt: skip
    race_day_changed(slot.event_id, {
        # everyone: names and times (leaderboard.live.spectator_status keeps only these)
        "over": True, "winner": winner.get("name") if winner else None,
        "winner_time_s": winner.get("total_time_s") if winner and winner.get("finished")
        else None, "standings": race_standings(race.car_rows),
        # those who run the event: the race, its status and error, the raw results
        "race": race_id, "status": race.status, "error": race.error, "results": race.results,
    })  # fmt: skip
    return slot


def race_day_stop(*, event: Event, user) -> bool:
    """Stop the race on track, through training's service (the league writes no race job).
    A race a worker is driving stops at its next step and keeps what it drove; the turn is
    done when it has stopped. One still queued (no worker has claimed it yet) is canceled at
    once: it never starts, its share of the organiser's job quota is freed, and the turn ends
    now (training's ``race_finished``, through :mod:`leaderboard.racefinish`). Returns True
    when the race was canceled so, False when it is stopping."""
    _check(event, user)
    slot = RaceDaySlot.objects.filter(event=event, status=RaceDaySlot.Status.RUNNING).first()
    if slot is None or slot.race is None:
        raise LeagueError("no race is on track")
    race = slot.race
    race_stop(race=race, by=f"race day of event {event.pk} ({user})", cancel_queued=True)
    return race.status == JobStatus.CANCELED


def race_day_spectator_link(*, event: Event, user, enabled: bool) -> str:
    """Turn the read-only spectator link on (a new token) or off; returns the token. Either
    way the old link stops working at once: its open broadcast sockets are told to check
    their access again and close (:func:`broadcast_access_changed`)."""
    _check(event, user)
    token = secrets.token_urlsafe(18) if enabled else ""
    Event.objects.filter(pk=event.pk).update(spectator_token=token)
    event.spectator_token = token
    event_id = event.pk
    transaction.on_commit(lambda: broadcast_access_changed(event_id))
    return token


def _notify_next(event: Event) -> None:
    """Tell the racer(s) of the first waiting turn they are up next (once per turn); with live
    speed control on, the notice opens their speed page."""
    slot = RaceDaySlot.objects.filter(event=event, status=RaceDaySlot.Status.WAITING).first()
    if slot is None or slot.notified:
        return
    subs = [slot.submission] if slot.submission_id else [slot.match.top, slot.match.bottom]
    for sub in subs:
        if sub is not None:
            speed = event.live_speed_control
            link = reverse("league-race-speed" if speed else "league-event", args=[event.pk])
            Notification.objects.create(user=sub.racer, link=link,
                                        message=f"You're up next at {event.name}'s race day "
                                        f"({sub.model_name})"
                                        f"{': set your speed here' if speed else ''}.")  # fmt: skip
    RaceDaySlot.objects.filter(pk=slot.pk).update(notified=True)
