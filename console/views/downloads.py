"""Downloads of a user's own models and evaluations (404 for anyone else's). The car model
is built by a worker (a page with its progress, then the download from the store)."""

from __future__ import annotations

from collections.abc import Callable

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.urls import reverse
from django.views.decorators.http import require_safe

from console.views.owned import owned_evaluation, owned_model
from training.http import media_response
from training.models import RacingModel
from training.services import ServiceError, background, downloads

GZIP, ONNX = "application/gzip", "application/octet-stream"
#: The car and virtual-model archives are named as DeepRacer-on-AWS names its downloads
#: (``physicalmodel-<name>.tar.gz``, ``virtualmodel-<name>.tar.gz``: its
#: source/libs/lambda/src/api/handlers/getAssetUrl.ts).
ARCHIVES: dict[str, tuple[Callable[[RacingModel], bytes], str, str]] = {
    "car": (downloads.car_model_archive, "physicalmodel-{name}.tar.gz", GZIP),
    "onnx": (downloads.onnx_policy, "{name}-policy.onnx", ONNX),
    "virtual": (downloads.virtual_model_archive, "virtualmodel-{name}.tar.gz", GZIP),
    "logs": (downloads.logs_archive, "{name}-logs.tar.gz", GZIP),
}


@login_required
@require_safe
def model_download(request: HttpRequest, model_id: int, kind: str) -> HttpResponse:
    model = owned_model(request, model_id)
    if kind not in ARCHIVES:
        raise Http404("No such download")
    build, filename, content_type = ARCHIVES[kind]
    try:
        if kind == "car":  # built by a worker (heavy): served once it is in the store
            data = background.car_export_ready(model)
            if data is None:
                return _preparing(request, model, filename.format(name=model.name))
        else:
            data = build(model)
    except ServiceError as exc:
        messages.error(request, exc.sentence)
        if request.GET.get("back") == "list":
            return redirect("models")
        return redirect("model-detail", model_id=model.pk)
    response = HttpResponse(data, content_type=content_type)
    response["Content-Disposition"] = f'attachment; filename="{filename.format(name=model.name)}"'
    return response


def _preparing(request: HttpRequest, model: RacingModel, filename: str) -> HttpResponse:
    """Queue (or follow) the worker that builds the car archive; the page polls it and then
    offers the download. Raises ServiceError when it cannot be started."""
    task_id = background.car_export_start(model=model, user=request.user)
    context = {"nav": "models", "model": model, "filename": filename,
               "task_poll": reverse("background-task", args=[task_id])}  # fmt: skip
    return render(request, "models/preparing.html", context, status=202)


@login_required
@require_safe
def evaluation_video(request: HttpRequest, evaluation_id: int) -> HttpResponse:
    evaluation = owned_evaluation(request, evaluation_id)
    try:
        data = downloads.evaluation_video(evaluation)
    except ServiceError:
        raise Http404("This evaluation has no video") from None
    return media_response(
        request, data, content_type="video/mp4", filename=f"evaluation-{evaluation.pk}.mp4"
    )
