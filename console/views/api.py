"""JSON endpoints used by the pages' JavaScript."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.urls import reverse
from django.views.decorators.http import require_http_methods, require_safe

from training import services
from training.catalog import MAX_SOURCE_CHARS
from training.services import background, rewards

#: The largest request a source at the limit can make: 12 bytes a character when a form
#: percent-encodes 4-byte UTF-8, JSON escapes take at most 6. Anything larger is refused
#: before it is read, with the one message for a source that is too long.
MAX_BODY_BYTES = MAX_SOURCE_CHARS * 12 + 4096
OPENAPI_PATH = Path(__file__).resolve().parent.parent / "openapi.json"


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
@require_safe
def background_task(request: HttpRequest, task_id: str) -> JsonResponse:
    """GET: where the user's import or car export is: ``{status: queued|running}``, then
    ``{status: done, ok, error?}`` with ``next`` (the imported model's page) or ``download``
    (the car archive, ready in the store). 404 for an id that is not the user's."""
    try:
        status = dict(background.background_status(user_id=request.user.pk, task_id=task_id))
    except background.TaskNotFound:
        return JsonResponse({"error": "No such task."}, status=404)
    if status["status"] == "done" and status.get("ok"):
        model_id = status["model_id"]
        if status["kind"] == "import":
            status["next"] = reverse("model-detail", args=[model_id])
            messages.success(request, f"Model {status.get('name', '')} imported.")
            if note := status.get("note"):
                messages.warning(request, note[:1].upper() + note[1:])
        else:
            status["download"] = reverse("model-download", args=[model_id, "car"])
    return JsonResponse(status)


def _declared_length(request: HttpRequest) -> int:
    """The body's Content-Length, read before the body is (0 when absent or unreadable)."""
    try:
        return int(request.META.get("CONTENT_LENGTH") or 0)
    except ValueError:
        return 0


@login_required
@require_http_methods(["GET", "POST"])
def reward_validate(request: HttpRequest) -> JsonResponse:
    """POST ``{source, track, direction}`` (JSON or form data) starts a validation; GET
    ``?id=<id>`` polls it. The web process runs none of the user's code: static errors
    (found by parsing alone) come back at once with ``status: done``; otherwise the answer is
    202 ``{status: queued, id, poll}`` and polling gives ``{status: queued|running}`` until
    ``{status: done, ok, errors, rewards}``.

    Errors are DeepRacer's: ``{type, message, line, column, lineNumber}``; a request we cannot
    read, or one over the per-user limits, answers 400 (429 for limits) with one REQUEST_ERROR;
    a body too large for any source within the limit, 413 with the SYNTAX_ERROR every other
    way of checking gives a source that is too long.
    """
    if request.method == "GET":
        try:
            status = rewards.reward_validation_status(
                user_id=request.user.pk, task_id=request.GET.get("id", "")
            )
        except rewards.ValidationNotFound:
            return _error("No such validation.", status=404)
        return JsonResponse(dict(status))
    if _declared_length(request) > MAX_BODY_BYTES or len(request.body) > MAX_BODY_BYTES:
        too_long = {**rewards.reward_too_long_error(), "field": "source"}
        body = {"status": "done", "ok": False, "errors": [too_long], "rewards": {}}
        return JsonResponse(body, status=413)
    if request.content_type == "application/json":
        try:
            payload = json.loads(request.body or b"{}")
        except ValueError:
            return _error("The request body is not valid JSON.")
        except RecursionError:  # valid JSON nested past what the parser takes
            return _error("The request body is nested too deeply to read.")
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
    static = rewards.reward_parse_errors(source=source)
    try:
        if static:  # parsing only: answered here, nothing queued
            services.check_track(track, direction)
            return JsonResponse({"status": "done", "ok": False, "errors": static, "rewards": {}})
        task_id = rewards.reward_validation_start(
            user_id=request.user.pk, source=source, track_id=track, direction=direction
        )
    except services.ServiceError as exc:
        field = {"track_id": "track", "reward_function": "source"}.get(exc.field or "", exc.field)
        limited = isinstance(exc, rewards.ValidationLimited)
        return _error(exc.sentence, status=429 if limited else 400, field=field)
    poll = f"{reverse('reward-validate')}?id={task_id}"
    return JsonResponse({"status": "queued", "id": task_id, "poll": poll}, status=202)
