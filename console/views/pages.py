"""Views of the console: thin, they only call selectors and render."""

from __future__ import annotations

import base64

from django.contrib import messages
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.utils.cache import get_conditional_response, patch_cache_control
from django.views.decorators.http import require_POST, require_safe

from console import tracks
from console.forms import TrackUploadForm, add_service_error
from training import services


def home(request: HttpRequest) -> HttpResponse:
    return render(request, "home.html", {"nav": "home"})


@require_safe
def track_gallery(request: HttpRequest) -> HttpResponse:
    return _gallery(request, TrackUploadForm())


def _gallery(
    request: HttpRequest, form: TrackUploadForm, status: int = 200, **extra
) -> HttpResponse:  # noqa: E501
    context = {"nav": "tracks", "rows": tracks.track_rows(), "upload_form": form, **extra}
    return render(request, "tracks.html", context, status=status)


@require_POST
def track_upload(request: HttpRequest) -> HttpResponse:
    """Preview (validate and draw) or import an uploaded track file."""
    if not request.user.is_authenticated:
        return redirect("/accounts/login/?next=/tracks/%23import")
    form = TrackUploadForm(request.POST, request.FILES)
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
        carried = TrackUploadForm(initial={
            "track_id": track_id, "name": name, "filename": filename,
            "data": base64.b64encode(data).decode(),
        })  # fmt: skip
        return _gallery(request, carried, jump="import", check=check,
                        preview_src="data:image/png;base64,"
                        + base64.b64encode(check.preview_png).decode())  # fmt: skip
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


def coming_soon(request: HttpRequest, *, nav: str, title: str) -> HttpResponse:
    """Placeholder for sections that later issues build (Models, League)."""
    return render(request, "coming_soon.html", {"nav": nav, "title": title})
