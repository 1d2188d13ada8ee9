"""The racer's phone page for live speed control on race day (:mod:`leaderboard.speed`).

``GET``: the car's multiplier and the buttons (−0.1, +0.1, 0.5×, 1.0×, 1.5×); a refusal (the
setting is off, not the user's turn) is a 403 page with the sentence. ``POST speed=<value>``
(CSRF): sets it; a JSON answer for the page's script (``Accept: application/json``:
``{"speed": 1.1}``, or ``{"error": <sentence>}`` with 403 or 400), else the page again.

``GET .../speed/turn.json``: whose turn it is, for the page's poll every few seconds
(static/js/race_speed.js): ``{"turn": true, "speed": 1.1, "driving": 1.1}`` (``driving``:
what the car drives at now, null before it drives) for the racer on track; a 403 with
``{"turn": false, "error": <sentence>}`` for anyone else who may see the event (the page's
refusal); a 404 for those who may not. The page polls it so that a racer waiting for their
turn gets the buttons, and a racer whose turn ended the sentence, without a reload.
"""

from __future__ import annotations

from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import get_object_or_404, render
from django.views.decorators.http import require_http_methods

from leaderboard import speed as speed_control
from leaderboard.access import LeagueError, can_view_event
from leaderboard.models import Event

PRESETS = (0.5, 1.0, 1.5)
NUDGE = 0.1


def _sentence(message: str) -> str:
    text = message[:1].upper() + message[1:]
    return text if text.endswith((".", "!", "?")) else text + "."


def _wants_json(request: HttpRequest) -> bool:
    return "application/json" in request.headers.get("Accept", "")


def _page(
    request: HttpRequest,
    event: Event,
    *,
    speed: float | None = None,
    error: str = "",
    status: int = 200,
    driving: float | None | bool = False,
) -> HttpResponse:
    """The page; ``driving``: what the car drives at now (None: not yet; False: not shown)."""
    lo, hi = speed_control.MIN_SPEED_MULTIPLIER, speed_control.MAX_SPEED_MULTIPLIER
    context = {
        "nav": "league",
        "event": event,
        "speed": speed,
        "error": error,
        "presets": PRESETS,
        "lower": max(lo, round((speed or 1.0) - NUDGE, 2)),
        "higher": min(hi, round((speed or 1.0) + NUDGE, 2)),
        "min": lo,
        "max": hi,
        "show_driving": driving is not False,
        "driving": driving if driving is not False else None,
    }
    return render(request, "leaderboard/speed.html", context, status=status)


def _viewable_event(request: HttpRequest, event_id: int) -> Event:
    """The event, when this user may see it; else a 404 (as for no event at all)."""
    event = get_object_or_404(Event, pk=event_id)
    if not can_view_event(request.user, event):
        raise Http404("No such event")
    return event


@login_required
@require_http_methods(["GET", "HEAD", "POST"])
def race_speed(request: HttpRequest, event_id: int) -> HttpResponse:
    event = _viewable_event(request, event_id)
    if request.method == "POST":
        try:
            value = speed_control.race_speed_change(
                event=event, user=request.user, multiplier=request.POST.get("speed", "")
            )
        except LeagueError as exc:
            status = 403 if isinstance(exc, speed_control.SpeedRefused) else 400
            if _wants_json(request):
                return JsonResponse({"error": _sentence(exc.message)}, status=status)
            current = None
            if status == 400:
                current = _current(event, request)
            return _page(request, event, speed=current, error=_sentence(exc.message), status=status)
        if _wants_json(request):
            return JsonResponse({"speed": value})
        return _page(request, event, speed=value)
    try:
        turn = speed_control.live_turn_of(event=event, user=request.user)
    except speed_control.SpeedRefused as exc:
        return _page(request, event, error=_sentence(exc.message), status=403)
    return _page(request, event, speed=turn.speed, driving=turn.driving)


@login_required
@require_http_methods(["GET", "HEAD"])
def race_speed_turn(request: HttpRequest, event_id: int) -> JsonResponse:
    event = _viewable_event(request, event_id)
    try:
        turn = speed_control.live_turn_of(event=event, user=request.user)
    except speed_control.SpeedRefused as exc:
        response = JsonResponse({"turn": False, "error": _sentence(exc.message)}, status=403)
    else:
        response = JsonResponse({"turn": True, "speed": turn.speed, "driving": turn.driving})
    response["Cache-Control"] = "no-store"
    return response


def _current(event: Event, request: HttpRequest) -> float | None:
    try:
        return speed_control.live_turn_of(event=event, user=request.user).speed
    except LeagueError:
        return None
