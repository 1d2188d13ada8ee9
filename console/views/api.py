"""JSON endpoints used by the pages' JavaScript."""

from __future__ import annotations

import json
import threading
from functools import cache
from pathlib import Path

from django.conf import settings
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.views.decorators.http import require_POST, require_safe

from training import services
from training.sandbox import MAX_SOURCE_CHARS

MAX_BODY_BYTES = MAX_SOURCE_CHARS * 4 + 4096
OPENAPI_PATH = Path(__file__).resolve().parent.parent / "openapi.json"
VALIDATE_WAIT_S = 30.0
"""How long a validation waits for a free slot before answering 503 "busy, try again"."""
_validations: threading.BoundedSemaphore | None = None
_validations_lock = threading.Lock()


def _validation_slots() -> threading.BoundedSemaphore:
    """At most ``RACECRAFT_VALIDATE_CONCURRENCY`` reward validations at once in this web
    process: each starts a sandboxed interpreter (about a CPU-second), and a burst of them must
    not starve the pages everyone else is loading."""
    global _validations
    with _validations_lock:
        if _validations is None:
            slots = int(getattr(settings, "RACECRAFT_VALIDATE_CONCURRENCY", 2))
            _validations = threading.BoundedSemaphore(max(1, slots))
        return _validations


@cache
def _openapi_text() -> str:
    return OPENAPI_PATH.read_text(encoding="utf-8")


@require_safe
def openapi_schema(request: HttpRequest) -> HttpResponse:
    """The OpenAPI 3 description of the JSON API (console/openapi.json)."""
    return HttpResponse(_openapi_text(), content_type="application/json")


def _error(message: str, status: int = 400, field: str | None = None) -> JsonResponse:
    error = {"type": "REQUEST_ERROR", "message": message, "line": None, "column": None,
             "lineNumber": None, "field": field}  # fmt: skip
    return JsonResponse({"ok": False, "errors": [error]}, status=status)


@login_required
@require_POST
def reward_validate(request: HttpRequest) -> JsonResponse:
    """POST ``{source, track, direction}`` (JSON or form data) → ``{ok, errors, rewards}``.

    Errors are DeepRacer's: ``{type, message, line, column, lineNumber}``; a request we cannot
    read answers 400 with one REQUEST_ERROR.
    """
    if len(request.body) > MAX_BODY_BYTES:
        return _error("The reward function is too long.", status=413, field="source")
    if request.content_type == "application/json":
        try:
            payload = json.loads(request.body or b"{}")
        except ValueError:
            return _error("The request body is not valid JSON.")
        if not isinstance(payload, dict):
            return _error("The request body must be a JSON object.")
    else:
        payload = request.POST.dict()
    source, track = payload.get("source"), payload.get("track")
    direction = payload.get("direction") or "native"
    if not isinstance(source, str):
        return _error("Send the reward function as 'source'.", field="source")
    if not isinstance(track, str) or not track:
        return _error("Choose a track to validate on.", field="track")
    if not isinstance(direction, str):
        return _error("'direction' must be native, ccw or cw.", field="direction")
    slots = _validation_slots()
    if not slots.acquire(timeout=VALIDATE_WAIT_S):
        response = _error("The validator is busy; try again in a moment.", status=503)
        response["Retry-After"] = "10"
        return response
    try:
        result = services.check_reward(source, track, direction)
    except services.RewardRejected as exc:
        return JsonResponse({"ok": False, "errors": exc.errors})
    except services.ServiceError as exc:
        field = {"track_id": "track", "reward_function": "source"}.get(exc.field or "", exc.field)
        return _error(exc.sentence, field=field)
    finally:
        slots.release()
    return JsonResponse({"ok": True, "errors": [], "rewards": result["rewards"]})
