"""League pages of head-to-head racing: the bracket, the facilitator's race day, the broadcast
page for a big screen, and a race's video. Thin: selectors and services do the work.

The broadcast page is open to whoever can see the event, and to anyone without an account who
has the event's spectator link (``?watch=<token>``); the race-day controls need the event's
organiser or a race facilitator, and answer 403 to anyone else.
"""

from __future__ import annotations

from collections.abc import Callable

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.urls import reverse
from django.views.decorators.http import require_safe

from leaderboard import bracket, raceday
from leaderboard.access import LeagueError, can_manage_event, can_view_event
from leaderboard.broadcast import may_watch
from leaderboard.models import BracketMatch, Event, RaceDaySlot, Submission
from leaderboard.selectors import bracket_rounds, leaderboard_rows, race_day_queue
from training.http import media_response
from training.models import RaceJob
from training.services.downloads import race_video


def _event(request: HttpRequest, event_id: int) -> Event:
    event = get_object_or_404(Event, pk=event_id)
    if not can_view_event(request.user, event):
        raise Http404("No such event")
    return event


def _sentence(exc: LeagueError) -> str:
    text = exc.message[:1].upper() + exc.message[1:]
    return text if text.endswith((".", "!", "?")) else text + "."


def _act(request: HttpRequest, action: Callable[[], str], back: str) -> HttpResponse:
    try:
        note = action()
        if note:
            messages.success(request, note)
    except LeagueError as exc:
        messages.error(request, _sentence(exc))
    return redirect(back)


def event_bracket(request: HttpRequest, event_id: int) -> HttpResponse:
    """The bracket (``?fragment=1``: only its rounds, for the live refresh); POST ``seed``
    (the organiser) or ``withdraw`` an entry (its racer or the organiser)."""
    event = _event(request, event_id)
    back = reverse("league-event-bracket", args=[event.pk])
    if request.method == "POST":
        if not request.user.is_authenticated:
            return redirect(f"{reverse('login')}?next={back}")
        if request.POST.get("action") == "seed":
            return _act(
                request,
                lambda: (
                    bracket.bracket_seed(event=event, user=request.user)
                    and "The bracket is seeded; the first races are on their way."
                ),
                back,
            )
        submission = get_object_or_404(Submission, pk=request.POST.get("submission") or 0,
                                       event=event)  # fmt: skip

        def withdraw() -> str:
            bracket.bracket_withdraw(event=event, user=request.user, submission=submission)
            return f"{submission.model_name} was withdrawn from the bracket."

        return _act(request, withdraw, back)
    context = {"nav": "league", "event": event, "rounds": bracket_rounds(event),
               "manager": can_manage_event(request.user, event)}  # fmt: skip
    if request.GET.get("fragment"):
        return render(request, "leaderboard/_bracket.html", context)
    return render(request, "leaderboard/bracket.html", context)


RACE_DAY_ACTIONS = ("add", "up", "down", "skip", "launch", "stop", "pause", "resume",
                    "spectators-on", "spectators-off")  # fmt: skip


@login_required
def race_day(request: HttpRequest, event_id: int) -> HttpResponse:
    """The facilitator's race day: the queue and its controls (403 for anyone else)."""
    event = _event(request, event_id)
    if not can_manage_event(request.user, event):
        return render(request, "leaderboard/race_day_refused.html",
                      {"nav": "league", "event": event}, status=403)  # fmt: skip
    back = reverse("league-race-day", args=[event.pk])
    if request.method == "POST":
        action = request.POST.get("action", "")
        if action not in RACE_DAY_ACTIONS:
            messages.error(request, "Unknown race-day action.")
            return redirect(back)
        return _act(request, lambda: _race_day_action(request, event, action), back)
    return render(request, "leaderboard/race_day.html", {
        "nav": "league", "event": event, "slots": race_day_queue(event),
        "entries": Submission.objects.filter(event=event).exclude(
            status=Submission.Status.FAILED).order_by("model_name"),
        "spectator_url": request.build_absolute_uri(
            f"{reverse('league-broadcast', args=[event.pk])}?watch={event.spectator_token}")
        if event.spectator_token else "",
    })  # fmt: skip


def _race_day_action(request: HttpRequest, event: Event, action: str) -> str:
    user = request.user
    if action == "add":
        sub = get_object_or_404(Submission, pk=request.POST.get("submission") or 0, event=event)
        raceday.race_day_add(event=event, user=user, submission=sub)
        return f"{sub.model_name} joined the queue."
    if action in ("up", "down", "skip"):
        slot = get_object_or_404(RaceDaySlot, pk=request.POST.get("slot") or 0, event=event)
        if action == "skip":
            raceday.race_day_skip(slot=slot, user=user)
            return "Skipped."
        raceday.race_day_move(slot=slot, user=user, up=action == "up")
        return ""
    if action == "launch":
        slot = raceday.race_day_launch(event=event, user=user)
        return f"On track: {slot.race.title if slot.race else 'the next race'}."
    if action == "stop":
        if raceday.race_day_stop(event=event, user=user):
            return "The race had not started: it is canceled, and the next turn can go on track."
        return "The race on track is stopping."
    if action in ("pause", "resume"):
        raceday.race_day_pause(event=event, user=user, paused=action == "pause")
        return "The race day is paused." if action == "pause" else "The race day goes on."
    on = action == "spectators-on"
    raceday.race_day_spectator_link(event=event, user=user, enabled=on)
    return "The spectator link is on." if on else "The spectator link is off."


@require_safe
def broadcast(request: HttpRequest, event_id: int) -> HttpResponse:
    """The broadcast page: made for a 1920×1080 screen or a streaming tool's browser source."""
    event = get_object_or_404(Event, pk=event_id)
    token = request.GET.get("watch", "")
    if not may_watch(request.user, event, token):
        raise Http404("No such event")
    if request.GET.get("fragment") == "board":
        return render(request, "leaderboard/_broadcast_board.html",
                      {"rows": leaderboard_rows(event)[:10]})  # fmt: skip
    running = (RaceDaySlot.objects.filter(event=event, status=RaceDaySlot.Status.RUNNING)
               .select_related("race").first())  # fmt: skip
    return render(request, "leaderboard/broadcast.html", {
        "event": event, "rows": leaderboard_rows(event)[:10], "watch": token,
        "race": running.race if running else None,
    })  # fmt: skip


@require_safe
def race_video_view(request: HttpRequest, race_id: int) -> HttpResponse:
    """A league race's broadcast MP4, for whoever can see its event."""
    race = get_object_or_404(RaceJob, pk=race_id, purpose="league")
    match = BracketMatch.objects.filter(race=race).select_related("event").first()
    slot = RaceDaySlot.objects.filter(race=race).select_related("event").first()
    event = match.event if match else slot.event if slot else None
    if event is None or not may_watch(request.user, event, request.GET.get("watch", "")):
        raise Http404("No such race")
    data = race_video(race)
    if data is None:
        raise Http404("No video")
    return media_response(request, data, content_type="video/mp4", filename=f"race-{race.pk}.mp4")
