"""Views of the console: thin, they only call selectors and render."""

from __future__ import annotations

import base64

from django.contrib import messages
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.utils.cache import get_conditional_response, patch_cache_control
from django.views.decorators.http import require_POST, require_safe

from console import throttle, tracks
from console.forms import (
    TrackUploadForm,
    add_service_error,
    track_upload_forget,
    track_upload_keep,
)
from console.race_form import RaceLayoutForm, TrackLayoutForm
from console.track_filters import TrackFilterForm
from training import services


def home(request: HttpRequest) -> HttpResponse:
    return render(request, "home.html", {"nav": "home"})


@require_safe
def track_gallery(request: HttpRequest) -> HttpResponse:
    return _gallery(request, TrackUploadForm())


def _gallery(
    request: HttpRequest, form: TrackUploadForm, status: int = 200, **extra
) -> HttpResponse:  # noqa: E501
    every = tracks.track_rows()
    choices = [(r.info.id, r.info.name) for r in every]
    sent = any(key.startswith("f-") for key in request.GET)  # the search and filter form
    filter_form = TrackFilterForm(request.GET if sent else None, rows=every, prefix="f")
    track_filter = filter_form.track_filter()
    rows = every if track_filter is None else [r for r in every if track_filter.matches(r)]
    layout_src = ""
    if "race_type" in request.GET:  # the race layout form was sent (GET: a page to link to)
        layout = TrackLayoutForm(request.GET, track_choices=choices)
        try:
            settings = layout.layout()
        except services.ServiceError as exc:
            if layout.is_valid():  # the services refused the race (the form has its own)
                add_service_error(layout, exc.message, exc.field)
        else:
            track_id = layout.cleaned_data["track"]
            try:
                if throttle.previews_limited(request):
                    raise ValueError(throttle.TOO_MANY_PREVIEWS)
                tracks.race_preview(track_id, *settings)
            except (ValueError, tracks.UnknownTrackError) as exc:
                add_service_error(layout, str(exc), None)
            else:
                query = request.GET.copy()
                query.pop("track", None)
                layout_src = f"/tracks/{track_id}/race.png?{query.urlencode()}"
        if not layout_src:
            status = 400
        extra.setdefault("jump", "layout")
    else:
        layout = TrackLayoutForm(track_choices=choices)
    context = {"nav": "tracks", "rows": rows, "total": len(every), "filter_form": filter_form,
               "upload_form": form, "layout_form": layout, "layout_src": layout_src,
               **_conditions_strip(request, choices), **extra}  # fmt: skip
    return render(request, "tracks.html", context, status=status)


def _conditions_strip(request: HttpRequest, choices: list[tuple[str, str]]) -> dict:
    """The outside-world strip's track (``?conditions_track=``, else the first) and pictures."""
    ids = [track_id for track_id, _ in choices]
    chosen = request.GET.get("conditions_track", "")
    track_id = chosen if chosen in ids else (ids[0] if ids else "")
    return {"conditions_track": track_id, "conditions_choices": choices,
            "conditions_strip": tracks.conditions_samples() if track_id else []}  # fmt: skip


@require_safe
def track_race_preview(request: HttpRequest, track_id: str) -> HttpResponse:
    """The track with a race's objects where an episode starts them (the query: the race
    settings of the wizard, ``direction``, ``seed``): a PNG, or 400 saying what is wrong."""
    if throttle.previews_limited(request):
        return HttpResponse(throttle.TOO_MANY_PREVIEWS, status=429, content_type="text/plain")
    try:
        preview = tracks.race_preview(track_id, *RaceLayoutForm(request.GET).layout())
    except tracks.UnknownTrackError:
        raise Http404(f"No track {track_id!r}") from None
    except (services.ServiceError, ValueError) as exc:
        message = exc.sentence if isinstance(exc, services.ServiceError) else str(exc)
        return HttpResponse(message, status=400, content_type="text/plain; charset=utf-8")
    response = HttpResponse(preview.png, content_type="image/png")
    response["ETag"] = f'"{preview.etag}"'
    patch_cache_control(response, public=True, max_age=3600)
    return get_conditional_response(request, etag=response["ETag"], response=response)


@require_POST
def track_upload(request: HttpRequest) -> HttpResponse:
    """Preview (validate and draw) or import an uploaded track file."""
    if not request.user.is_authenticated:
        return redirect("/accounts/login/?next=/tracks/%23import")
    form = TrackUploadForm(request.POST, request.FILES, user_id=request.user.pk)
    if not form.is_valid():
        return _gallery(request, form, status=400, jump="import")
    data, filename = form.upload()
    track_id = form.cleaned_data["track_id"] or services.default_track_id(filename)
    name = form.cleaned_data["name"]
    try:
        if "preview" in request.POST:
            check = services.track_check(data=data, track_id=track_id, name=name)
        else:
            info = services.track_import(user=request.user, data=data, track_id=track_id,
                                         name=name)  # fmt: skip
    except services.ServiceError as exc:
        add_service_error(form, exc.message, exc.field)
        return _gallery(request, form, status=400, jump="import")
    if "preview" in request.POST:
        kept = track_upload_keep(user_id=request.user.pk, data=data, filename=filename)
        carried = TrackUploadForm(initial={
            "track_id": track_id, "name": name, "filename": filename, "kept": kept,
        })  # fmt: skip
        return _gallery(request, carried, jump="import", check=check,
                        preview_src="data:image/png;base64,"
                        + base64.b64encode(check.preview_png).decode())  # fmt: skip
    track_upload_forget(user_id=request.user.pk)
    messages.success(request, f"Track {info.name} imported: {info.length_m:.2f} m long, "
                     f"{info.width_m:.2f} m wide. Every user can train on it now.")  # fmt: skip
    return redirect(f"/tracks/#track-{info.id}")


@require_safe
def track_preview(request: HttpRequest, track_id: str) -> HttpResponse:
    try:
        preview = tracks.track_preview(track_id)
    except tracks.UnknownTrackError:
        raise Http404(f"No track {track_id!r}") from None
    response = HttpResponse(preview.png, content_type="image/png")
    response["ETag"] = f'"{preview.etag}"'
    patch_cache_control(response, public=True, max_age=3600)
    # 304 Not Modified when the browser already has these bytes.
    return get_conditional_response(request, etag=response["ETag"], response=response)


@require_safe
def track_conditions_preview(request: HttpRequest, track_id: str, index: int) -> HttpResponse:
    """Picture ``index`` of the track's outside-world strip (:func:`tracks.conditions_samples`):
    the car's camera at the start line under sampled conditions; a PNG."""
    try:
        preview = tracks.conditions_preview(track_id, index)
    except (tracks.UnknownTrackError, IndexError):
        raise Http404(f"No such picture of track {track_id!r}") from None
    response = HttpResponse(preview.png, content_type="image/png")
    response["ETag"] = f'"{preview.etag}"'
    patch_cache_control(response, public=True, max_age=3600)
    return get_conditional_response(request, etag=response["ETag"], response=response)


def coming_soon(request: HttpRequest, *, nav: str, title: str) -> HttpResponse:
    """Placeholder for sections that later issues build (Models, League)."""
    return render(request, "coming_soon.html", {"nav": nav, "title": title})
