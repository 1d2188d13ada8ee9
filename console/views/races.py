"""The Races page: a racer races their models against their own and other racers' open models
(:mod:`training.services.challenges` holds every rule). Thin views:

/races/                    the racer's races, and who raced their open models
/races/new/                the New race form
/races/<id>/               a race: live view while it runs, then results, replay, sim-traces
/races/<id>/video.mp4      the replay (the challenger and the opponents' owners)
/races/<id>/traces.tar.gz  every car's sim-trace (the challenger only)
/races/<id>/stop/          POST: cancel a queued race, stop a running one (the challenger only)
/models/<id>/challenges/   POST: open or close a model to challenges (its owner)

Anyone else gets a 404, as for a race that does not exist.
"""

from __future__ import annotations

from typing import Any

from django import forms
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.views.decorators.http import require_http_methods, require_POST, require_safe

from console.views.owned import owned_model
from console.views.service_calls import attempt_on_form
from training.http import media_response
from training.models import Direction, RaceJob
from training.services import ServiceError, track_catalog
from training.services import challenges as service
from training.services.downloads import race_video


def _loops() -> list[tuple[str, str]]:
    return [(info.id, info.name) for info in track_catalog().list() if info.closed]


class NewRaceForm(forms.Form):
    model = forms.TypedChoiceField(label="Your car", coerce=int)
    opponents = forms.TypedMultipleChoiceField(
        label="Opponents", coerce=int, widget=forms.CheckboxSelectMultiple,
        help_text="One to three: your own models, and models their owners opened to challenges.",
        error_messages={"required": "Pick one to three opponents."},
    )  # fmt: skip
    track_id = forms.ChoiceField(label="Track")
    direction = forms.ChoiceField(choices=Direction.choices, initial=Direction.NATIVE)
    laps = forms.IntegerField(min_value=service.MIN_LAPS, max_value=service.MAX_LAPS, initial=3)
    bots = forms.IntegerField(label="Bot cars", min_value=service.MIN_BOTS,
                              max_value=service.MAX_BOTS, initial=0)  # fmt: skip

    def __init__(self, *args: Any, choices: service.ChallengeChoices, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fields["model"].choices = [(m.pk, m.name) for m in choices.mine]
        self.fields["opponents"].choices = [
            (m.pk, m.name if m in choices.mine else f"{m.name} ({m.owner.username})")
            for m in choices.opponents
        ]
        self.fields["track_id"].choices = _loops()


@login_required
@require_safe
def race_list(request: HttpRequest) -> HttpResponse:
    return render(request, "races/list.html", {
        "nav": "races",
        "races": service.races_started_by(user=request.user),
        "against": service.races_against(user=request.user),
    })  # fmt: skip


@login_required
@require_http_methods(["GET", "HEAD", "POST"])
def race_new(request: HttpRequest) -> HttpResponse:
    choices = service.challenge_choices(user=request.user)
    if request.method != "POST":
        initial = {"track_id": "racecraft_oval"}
        if request.GET.get("opponent", "").isdigit():
            initial["opponents"] = [int(request.GET["opponent"])]
        form = NewRaceForm(initial=initial, choices=choices)
        return render(request, "races/new.html", {"nav": "races", "form": form,
                                                  "choices": choices})  # fmt: skip
    form = NewRaceForm(request.POST, choices=choices)
    if form.is_valid():
        data = form.cleaned_data
        race, _ = attempt_on_form(form, lambda: service.challenge_start(
            user=request.user, model_id=data["model"], opponent_ids=data["opponents"],
            track_id=data["track_id"], direction=data["direction"], laps=data["laps"],
            bots=data["bots"]))  # fmt: skip
        if race is not None:
            note = getattr(race, "dispatch_note", "")
            if note:
                messages.warning(request, f"Race queued, but {note}.")
            else:
                messages.success(request, "Race queued: it starts as soon as a worker is free.")
            return redirect("race-detail", race_id=race.pk)
    return render(request, "races/new.html", {"nav": "races", "form": form, "choices": choices},
                  status=400)  # fmt: skip


def _race(request: HttpRequest, race_id: int, *, challenger_only: bool = False
          ) -> tuple[RaceJob, str]:  # fmt: skip
    try:
        return service.challenge_for(user=request.user, race_id=race_id,
                                     challenger_only=challenger_only)  # fmt: skip
    except RaceJob.DoesNotExist:
        raise Http404("No such race") from None


@login_required
@require_safe
def race_detail(request: HttpRequest, race_id: int) -> HttpResponse:
    """The challenger watches a race that is queued or on track on the broadcast view; the
    race's page (``?results=1``, or once it ended) has the result, replay and sim-traces."""
    race, role = _race(request, race_id)
    context = {"nav": "races", "race": race, "role": role,
               "challenger": role == service.CHALLENGER, "rows": service.result_rows(race),
               "ahead": service.jobs_ahead_of(race)}  # fmt: skip
    if context["challenger"] and race.is_active and not request.GET.get("results"):
        return render(request, "races/watch.html", context)
    return render(request, "races/detail.html", context)


@login_required
@require_safe
def race_video_view(request: HttpRequest, race_id: int) -> HttpResponse:
    race, _ = _race(request, race_id)
    try:
        data = race_video(race)
    except ServiceError:
        data = None
    if data is None:
        raise Http404("This race has no replay")
    return media_response(request, data, content_type="video/mp4", filename=f"race-{race.pk}.mp4")


@login_required
@require_safe
def race_traces(request: HttpRequest, race_id: int) -> HttpResponse:
    race, _ = _race(request, race_id, challenger_only=True)
    try:
        data = service.challenge_traces(race)
    except ServiceError as exc:
        messages.error(request, exc.sentence)
        return redirect("race-detail", race_id=race.pk)
    response = HttpResponse(data, content_type="application/gzip")
    response["Content-Disposition"] = f'attachment; filename="race-{race.pk}-simtraces.tar.gz"'
    return response


@login_required
@require_POST
def race_stop_view(request: HttpRequest, race_id: int) -> HttpResponse:
    """The challenger stops their race: a queued one is canceled at once; a running one stops
    at the worker's next step and keeps what was driven (the results so far, the replay and
    the sim-traces)."""
    race, _ = _race(request, race_id, challenger_only=True)
    outcome = service.challenge_stop(race=race, by=request.user.get_username())
    if outcome == service.CANCELED:
        messages.success(request, "Race canceled before it started: it will not run, and it "
                         "no longer counts against your job quota.")  # fmt: skip
    elif outcome == service.STOPPING:
        messages.success(request, "Stopping the race: what was driven is kept.")
    else:
        messages.info(request, "This race has already ended.")
    return redirect("race-detail", race_id=race.pk)


@login_required
@require_POST
def model_challenges(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    open_ = request.POST.get("open") == "1"
    service.model_challenges_set(model=model, user=request.user, open_=open_)
    if open_:
        messages.success(request, f"{model.name} is open to challenges: other racers can "
                         "race a frozen copy of it; your Races page shows who did.")  # fmt: skip
    else:
        messages.success(request, f"{model.name} is closed to challenges; races already run "
                         "keep their results and replays.")  # fmt: skip
    return redirect(f"/models/{model.pk}/#challenges")
