"""Readiness for the real car (issue 51): start a check from the model page, its table and
verdict there, the worst cells' videos (the owner's only), and two models' tables side by side.

``/readiness/<id>/progress.json`` (the owner's only; 404 for anyone else, as for a missing
check): how far a check got, which the model page polls every few seconds while it runs
(static/js/readiness_progress.js); without JavaScript the page says to reload."""

from __future__ import annotations

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import redirect, render
from django.views.decorators.http import require_http_methods, require_POST

from console.templatetags.racecraft import badge
from console.views.owned import owned_model, say_queued
from training import services
from training.http import media_response
from training.models import RacingModel, ReadinessCheck
from training.services import readiness as readiness_services


def readiness_context(model: RacingModel) -> dict:
    """What the model page's "Readiness for the real car" section shows."""
    check = readiness_services.readiness_latest(model)
    return {
        "readiness": check,
        "readiness_grid": readiness_services.readiness_grid(check),
        "readiness_ahead": services.jobs_ahead(check),
    }


def _owned_check(request: HttpRequest, check_id: int) -> ReadinessCheck:
    try:
        return readiness_services.readiness_for_owner(request.user, check_id)
    except ReadinessCheck.DoesNotExist:
        raise Http404("No such readiness check") from None


@login_required
@require_POST
def readiness_start(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    try:
        check = readiness_services.readiness_start(model=model, user=request.user)
    except services.ServiceError as exc:
        messages.error(request, exc.sentence)
    else:
        say_queued(request, check, "Readiness check queued.")
    return redirect(f"/models/{model.pk}/#readiness")


@login_required
@require_POST
def readiness_stop(request: HttpRequest, check_id: int) -> HttpResponse:
    check = _owned_check(request, check_id)
    try:
        services.job_stop(job=check, user=request.user)
    except services.ServiceError as exc:
        messages.error(request, exc.sentence)
    return redirect(f"/models/{check.model_id}/#readiness")


@login_required
@require_http_methods(["GET", "HEAD"])
def readiness_progress(request: HttpRequest, check_id: int) -> JsonResponse:
    """The check's state for the model page's poll: ``status`` (and its words and badge),
    ``active``, ``cells_done`` of ``cells_total``, ``percent`` (0-100) and ``ahead`` (jobs
    before it in the fair order while queued, else null)."""
    check = _owned_check(request, check_id)
    total = check.cells_total
    response = JsonResponse({
        "status": check.status, "status_display": check.get_status_display(),
        "badge": badge(check.status), "active": check.is_active,
        "cells_done": check.cells_done, "cells_total": total,
        "percent": round(100 * check.cells_done / total) if total else 0,
        "ahead": services.jobs_ahead(check),
    })  # fmt: skip
    response["Cache-Control"] = "no-store"
    return response


@login_required
@require_http_methods(["GET", "HEAD"])
def readiness_video(request: HttpRequest, check_id: int, key: str) -> HttpResponse:
    check = _owned_check(request, check_id)
    try:
        data = readiness_services.readiness_video(check, key)
    except services.ServiceError:
        raise Http404("This readiness check has no such video") from None
    return media_response(request, data, content_type="video/mp4",
                          filename=f"readiness-{check.pk}-{key}.mp4")  # fmt: skip


def _model_id(value: str | None) -> int | None:
    return int(value) if value and value.isdigit() and len(value) < 12 else None


@login_required
@require_http_methods(["GET", "HEAD"])
def readiness_compare(request: HttpRequest) -> HttpResponse:
    choices = readiness_services.readiness_finished_models(request.user)
    a, b = _model_id(request.GET.get("a")), _model_id(request.GET.get("b"))
    context: dict = {"nav": "models", "choices": choices, "a": a, "b": b, "pairs": None}
    status = 200
    if "a" in request.GET or "b" in request.GET:
        try:
            pairs = readiness_services.readiness_compare(user=request.user, model_ids=[a, b])
        except services.ServiceError as exc:
            context["error"], status = exc.sentence, 400
        else:
            context["pairs"] = pairs
            context["rows"] = readiness_services.readiness_rows([c for _, c in pairs])
    return render(request, "models/readiness_compare.html", context, status=status)
