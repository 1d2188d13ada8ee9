"""A model's analysis page and its chart data (JSON or CSV), and reward replays: the owner's
models only (404 for anyone else's). The server aggregates, the browser draws."""

from __future__ import annotations

import json

from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import render
from django.views.decorators.http import require_POST, require_safe

from console.views.owned import owned_model
from training.services import ServiceError
from training.services import analysis as service


@login_required
@require_safe
def analysis_page(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    return render(request, "models/analysis.html", {
        "nav": "models", "model": model, "charts": service.CHARTS,
        "track": service.track_outline(model),
    })  # fmt: skip


def _refused(exc: ServiceError) -> JsonResponse:
    return JsonResponse({"error": exc.sentence}, status=400)


@login_required
@require_safe
def analysis_data(request: HttpRequest, model_id: int, chart: str, fmt: str) -> HttpResponse:
    """``<chart>.json`` or ``<chart>.csv``; ``?kind=reward|speed|action`` for the heatmap."""
    model = owned_model(request, model_id)
    kind = request.GET.get("kind", "reward")
    try:
        if fmt == "csv":
            response = HttpResponse(service.analysis_csv(model, chart, kind=kind),
                                    content_type="text/csv")  # fmt: skip
            response["Content-Disposition"] = f'attachment; filename="{model.name}-{chart}.csv"'
            return response
        return JsonResponse(service.analysis_chart(model, chart, kind=kind))
    except ServiceError as exc:
        return _refused(exc)


@login_required
@require_safe
def analysis_episode(request: HttpRequest, model_id: int, iteration: int, episode: int):
    model = owned_model(request, model_id)
    try:
        return JsonResponse(service.analysis_episode(model, iteration, episode))
    except ServiceError as exc:
        return _refused(exc)


@login_required
@require_POST
def replay_start(request: HttpRequest, model_id: int) -> JsonResponse:
    """Body ``{"iteration", "episode", "reward_function"}``; answers ``{"task": id}``."""
    model = owned_model(request, model_id)
    try:
        body = json.loads(request.body or b"{}")
        task = service.replay_start(model=model, iteration=int(body["iteration"]),
                                    episode=int(body["episode"]),
                                    source=str(body["reward_function"]))  # fmt: skip
    except (ValueError, KeyError, TypeError, RecursionError):  # RecursionError: nested JSON
        return JsonResponse({"error": "send iteration, episode and reward_function"}, status=400)
    except ServiceError as exc:
        return _refused(exc)
    return JsonResponse({"task": task}, status=202)


@login_required
@require_safe
def replay_result(request: HttpRequest, model_id: int, task_id: str) -> JsonResponse:
    model = owned_model(request, model_id)
    return JsonResponse(service.replay_result(model=model, task_id=task_id))
