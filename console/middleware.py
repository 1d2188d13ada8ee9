"""Answers for the failures a user can do nothing about but wait: the object store or the
database is unreachable. Instead of a 500 (and a traceback in debug mode) the user gets a 503
"... unavailable, try again" (JSON for the API, a short page otherwise) with Retry-After, and
the next request starts afresh (Django drops a broken database connection at its end)."""

from __future__ import annotations

import logging
import time

from django.conf import settings
from django.db import DatabaseError, InterfaceError, OperationalError
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.utils.html import escape

from console import tracks
from training import services
from training.errors import ObjectNotFound, StoreError

log = logging.getLogger(__name__)
RETRY_AFTER_S = 30

PAGE = """<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>{title} - Racecraft</title><link rel="stylesheet" href="/static/css/app.css"></head>
<body><main class="page"><h1>{title}</h1><p>{message}</p>
<p><a href="javascript:location.reload()">Try again</a> or go back to <a href="/">the console</a>.
</p></main></body></html>"""


def unavailable_response(request: HttpRequest, what: str) -> HttpResponse:
    message = f"The {what} is unavailable right now; nothing was changed. Try again in a minute."
    if request.path.startswith("/api/") or "application/json" in request.headers.get("Accept", ""):
        response: HttpResponse = JsonResponse({"error": message, "unavailable": what}, status=503)
    else:
        title = f"{what[0].upper()}{what[1:]} unavailable"
        response = HttpResponse(PAGE.format(title=escape(title), message=escape(message)),
                                status=503)  # fmt: skip
    response["Retry-After"] = str(RETRY_AFTER_S)
    return response


class UnavailableMiddleware:
    """Turns an unreachable store or database into a 503 "try again"."""

    def __init__(self, get_response) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        return self.get_response(request)

    def process_exception(self, request: HttpRequest, exception: Exception) -> HttpResponse | None:
        if isinstance(exception, StoreError) and not isinstance(exception, ObjectNotFound):
            what = "model store"
        elif isinstance(exception, OperationalError | InterfaceError):
            what = "database"
        else:
            return None
        log.warning("%s %s: %s unavailable: %s", request.method, request.path, what, exception)
        return unavailable_response(request, what)


class TrackSyncMiddleware:
    """The web's tracks folder follows the database: imported tracks are recorded there
    (:class:`~training.models.TrackFile`), and at most once every ``RACECRAFT_TRACKS_SYNC_S``
    seconds a web process writes those its folder lacks or holds in another version
    (one small query when nothing changed). A second web host, a rebuilt one, or a track
    imported on another machine is listed, previewed and accepted like the web's own uploads;
    previews of a track written anew are drawn again. 0 turns it off."""

    def __init__(self, get_response) -> None:
        self.get_response = get_response
        self.next_at = 0.0

    def __call__(self, request: HttpRequest) -> HttpResponse:
        every = float(getattr(settings, "RACECRAFT_TRACKS_SYNC_S", 0))
        now = time.monotonic()
        if every > 0 and now >= self.next_at:
            self.next_at = now + every
            try:
                if services.tracks_sync():
                    tracks.preview_cache_clear()
            except (DatabaseError, OSError):
                log.warning("could not bring the tracks folder up to date", exc_info=True)
        return self.get_response(request)
