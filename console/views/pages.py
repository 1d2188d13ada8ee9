"""Views of the console: thin, they only call selectors and render."""

from __future__ import annotations

from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import render
from django.utils.cache import get_conditional_response, patch_cache_control
from django.views.decorators.http import require_safe

from console import tracks


def home(request: HttpRequest) -> HttpResponse:
    return render(request, "home.html", {"nav": "home"})


@require_safe
def track_gallery(request: HttpRequest) -> HttpResponse:
    return render(request, "tracks.html", {"nav": "tracks", "rows": tracks.track_rows()})


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
