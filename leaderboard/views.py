"""League pages: thin views that call selectors and services and render.

A private event the user may not see answers 404, as if it did not exist.
"""

from __future__ import annotations

from collections.abc import Callable

from django.contrib import messages
from django.contrib.auth import get_user_model
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.urls import reverse
from django.views.decorators.http import require_POST, require_safe

from leaderboard import events as event_services
from leaderboard import selectors
from leaderboard.access import LeagueError, can_manage_event, can_view_event, is_facilitator
from leaderboard.divisions import division_for
from leaderboard.forms import EventForm, ProfileForm, SubmitForm
from leaderboard.models import Event, Submission
from leaderboard.profiles import notifications_mark_read, profile_for, profile_update
from leaderboard.services import submission_create
from training.http import media_response
from training.services import ServiceError
from training.services.downloads import evaluation_video


def _visible_event(request: HttpRequest, event_id: int) -> Event:
    event = get_object_or_404(Event.objects.select_related("season", "organiser"), pk=event_id)
    if not can_view_event(request.user, event):
        raise Http404("No such event")
    return event


def _sentence(exc: LeagueError) -> str:
    """A refusal as a sentence: capital first letter, full stop."""
    text = exc.message[:1].upper() + exc.message[1:]
    return text if text.endswith((".", "!", "?")) else text + "."


def _form_error(form, exc: LeagueError) -> None:
    form.add_error(exc.field if exc.field in form.fields else None, exc.message)


def league_home(request: HttpRequest) -> HttpResponse:
    user = request.user
    profile = profile_for(user) if user.is_authenticated else None
    form = ProfileForm(profile=profile) if profile else None
    if request.method == "POST":
        if profile is None:
            return redirect(f"{reverse('login')}?next={request.path}")
        form = ProfileForm(request.POST, profile=profile)
        if form.is_valid():
            try:
                profile_update(user=user, **form.cleaned_data)
                messages.success(request, "Profile saved.")
                return redirect("league")
            except LeagueError as exc:
                _form_error(form, exc)
    upcoming, recent = selectors.upcoming_and_recent_events()
    notifications = selectors.notifications_for(user)  # read before marking: new ones glow once
    if notifications:
        notifications_mark_read(user=user)
    return render(request, "leaderboard/home.html", {
        "nav": "league",
        "profile": profile,
        "profile_form": form,
        "division": division_for(user) if user.is_authenticated else None,
        "open_events": selectors.open_events_for(user),
        "upcoming": upcoming,
        "recent": recent,
        "seasons": selectors.seasons_with_events(user),
        "community": selectors.community_races_for(user),
        "notifications": notifications,
        "is_facilitator": is_facilitator(user),
    })  # fmt: skip


def _event_form_view(request: HttpRequest, *, public: bool, event: Event | None = None):
    initial = {name: getattr(event, name) for name in event_services.EVENT_FIELDS} if event else {}
    form = EventForm(request.POST or None, public=public, initial=initial)
    if request.method == "POST" and form.is_valid():
        try:
            if event is None:
                event = event_services.event_create(
                    organiser=request.user, is_private=not public, **form.event_fields()
                )
                messages.success(request, f"{event.name} is set up.")
            else:
                event = event_services.event_update(
                    event=event, user=request.user, **form.event_fields()
                )
                messages.success(request, "Event saved.")
            return redirect("league-event", event.pk)
        except LeagueError as exc:
            _form_error(form, exc)
    title = (
        f"Edit {event.name}" if event else ("New league event" if public else "New community race")
    )
    return render(request, "leaderboard/event_form.html", {
        "nav": "league", "form": form, "event": event, "title": title, "public": public,
    })  # fmt: skip


@login_required
def event_create(request: HttpRequest) -> HttpResponse:
    if not is_facilitator(request.user):
        messages.info(request, "Only race facilitators create league events; "
                               "you can organise a community race.")  # fmt: skip
        return redirect("league-community-create")
    return _event_form_view(request, public=True)


@login_required
def community_create(request: HttpRequest) -> HttpResponse:
    return _event_form_view(request, public=False)


@login_required
def event_edit(request: HttpRequest, event_id: int) -> HttpResponse:
    event = _visible_event(request, event_id)
    if not can_manage_event(request.user, event):
        raise Http404("No such event")
    return _event_form_view(request, public=not event.is_private, event=event)


def _invite_url(request: HttpRequest, event: Event) -> str:
    return request.build_absolute_uri(reverse("league-join", args=[event.invite_token]))


@require_safe
def event_detail(request: HttpRequest, event_id: int) -> HttpResponse:
    event = _visible_event(request, event_id)
    if request.GET.get("screen"):
        return event_screen(request, event_id)
    user = request.user
    manager = can_manage_event(user, event)
    models = selectors.ready_models_of(user)
    return render(request, "leaderboard/event.html", {
        "nav": "league",
        "event": event,
        "rows": selectors.leaderboard_rows(event),
        "mine": selectors.submissions_of(event, user),
        "submit_form": SubmitForm(models=models) if user.is_authenticated else None,
        "has_models": models.exists(),
        "manager": manager,
        "all_submissions": selectors.all_submissions(event) if manager else None,
        "entrants": selectors.entrants_of(event) if manager and event.is_private else None,
        "invite_url": _invite_url(request, event) if manager and event.is_private else "",
        "is_open": event.is_open(),
        "needs_alias": user.is_authenticated and not profile_for(user).alias,
    })  # fmt: skip


@require_safe
def event_screen(request: HttpRequest, event_id: int) -> HttpResponse:
    """The wide-screen view for a big display: large type, no navigation, live."""
    event = _visible_event(request, event_id)
    return render(request, "leaderboard/screen.html", {
        "event": event, "rows": selectors.leaderboard_rows(event),
    })  # fmt: skip


@login_required
@require_POST
def event_submit(request: HttpRequest, event_id: int) -> HttpResponse:
    event = _visible_event(request, event_id)
    form = SubmitForm(request.POST, models=selectors.ready_models_of(request.user))
    if not form.is_valid():
        messages.error(request, "Choose one of your models.")
        return redirect("league-event", event.pk)
    try:
        submission = submission_create(event=event, user=request.user,
                                       model=form.cleaned_data["model"])  # fmt: skip
        messages.success(request, f"{submission.model_name} is submitted: it is being "
                                  "evaluated on the event's track.")  # fmt: skip
    except LeagueError as exc:
        messages.error(request, _sentence(exc))
    return redirect("league-event", event.pk)


def _manage(request: HttpRequest, event_id: int, action: Callable[[Event], str]) -> HttpResponse:
    event = _visible_event(request, event_id)
    try:
        note = action(event)
        if note:
            messages.success(request, note)
    except LeagueError as exc:
        messages.error(request, _sentence(exc))
    return redirect("league-event", event.pk)


@login_required
@require_POST
def event_close(request: HttpRequest, event_id: int) -> HttpResponse:
    def close(event: Event) -> str:
        event_services.event_close(event=event, user=request.user)
        return "The event is closed."

    return _manage(request, event_id, close)


@login_required
@require_POST
def event_invite_reset(request: HttpRequest, event_id: int) -> HttpResponse:
    def reset(event: Event) -> str:
        event_services.event_invite_reset(event=event, user=request.user)
        return "A new invite link is ready; the old one no longer works."

    return _manage(request, event_id, reset)


@login_required
@require_POST
def event_participant_remove(request: HttpRequest, event_id: int, racer_id: int) -> HttpResponse:
    racer = get_object_or_404(get_user_model(), pk=racer_id)

    def remove(event: Event) -> str:
        event_services.event_participant_remove(event=event, user=request.user, racer=racer)
        return f"{racer.get_username()} was removed from the race."

    return _manage(request, event_id, remove)


@login_required
def event_join(request: HttpRequest, token: str) -> HttpResponse:
    """The invite link: a page with the race and a Join button."""
    try:
        event = event_services.event_for_invite(token=token)
    except LeagueError as exc:
        return render(request, "leaderboard/join.html", {"nav": "league", "error": exc.message},
                      status=404)  # fmt: skip
    if can_view_event(request.user, event):
        return redirect("league-event", event.pk)
    if request.method == "POST":
        try:
            event_services.event_join(token=token, user=request.user)
            messages.success(request, f"You joined {event.name}.")
            return redirect("league-event", event.pk)
        except LeagueError as exc:
            return render(request, "leaderboard/join.html",
                          {"nav": "league", "error": exc.message}, status=403)  # fmt: skip
    return render(request, "leaderboard/join.html", {"nav": "league", "event": event})


def _watchable(request: HttpRequest, submission_id: int) -> Submission:
    submission = get_object_or_404(
        Submission.objects.select_related("event", "evaluation", "racer"), pk=submission_id
    )
    if not selectors.can_watch_submission(request.user, submission):
        raise Http404("No such submission")
    return submission


@require_safe
def submission_detail(request: HttpRequest, submission_id: int) -> HttpResponse:
    submission = _watchable(request, submission_id)
    return render(request, "leaderboard/submission.html", {
        "nav": "league", "submission": submission, "event": submission.event,
        "alias": profile_for(submission.racer).alias or f"racer-{submission.racer_id}",
    })  # fmt: skip


@require_safe
def submission_video(request: HttpRequest, submission_id: int) -> HttpResponse:
    submission = _watchable(request, submission_id)
    if submission.evaluation is None:
        raise Http404("No video")
    try:
        data = evaluation_video(submission.evaluation)
    except ServiceError:
        raise Http404("No video") from None
    return media_response(
        request, data, content_type="video/mp4", filename=f"submission-{submission.pk}.mp4"
    )
