"""A model's page: its configuration, training (start, stop, live chart and video) and
evaluations (start, progress, results, video)."""

from __future__ import annotations

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.views.decorators.http import require_http_methods, require_POST

from console import tracks
from console.forms import EvaluateForm
from console.model_form import HP_LABELS, PPO_ONLY, SAC_ONLY
from console.race_form import race_initial
from console.views.owned import owned_evaluation, owned_model, owned_training_job, say_queued
from console.views.readiness import readiness_context
from console.views.service_calls import attempt, attempt_on_form
from training import catalog, selectors, services
from training.models import RacingModel

SENSOR_LABELS = {"FRONT_FACING_CAMERA": "Camera", "STEREO_CAMERAS": "Stereo camera",
                 "LIDAR": "LIDAR", "SECTOR_LIDAR": "Sector LIDAR",
                 "DISCRETIZED_SECTOR_LIDAR": "Discretized sector LIDAR"}  # fmt: skip
ALGORITHM_LABELS = {"clipped_ppo": "PPO", "sac": "SAC"}


def hyperparameter_rows(model: RacingModel) -> list[tuple[str, object]]:
    skip = PPO_ONLY if model.algorithm == "sac" else SAC_ONLY
    return [
        (label, model.hyperparameters.get(key))
        for key, label in HP_LABELS.items()
        if key not in skip and key in model.hyperparameters
    ]


def _page(request: HttpRequest, model: RacingModel, evaluate_form: EvaluateForm | None = None,
          status: int = 200) -> HttpResponse:  # fmt: skip
    job = selectors.latest_training_job(model)
    evaluations = selectors.evaluations_of(model)
    track_names = {r.info.id: r for r in tracks.track_rows()}
    if evaluate_form is None:
        evaluate_form = EvaluateForm(
            initial={"track_id": model.track_id, "direction": model.direction,
                     **race_initial(model.race_type, model.race_config)}
        )  # fmt: skip
    actions = selectors.model_actions(model, job)
    points = selectors.chart_points(job) if job else []
    context = {
        "nav": "models",
        "model": model,
        "track": track_names.get(model.track_id),
        "track_names": {k: r.info.name for k, r in track_names.items()},
        "sensor_labels": [SENSOR_LABELS.get(s, s) for s in model.sensors],
        "sensor_advice": services.sensor_advice(model.race_type, model.sensors),
        "droa_refusal": services.deepracer_on_aws_refusal(model) if model.has_checkpoint else None,
        "algorithm_label": ALGORITHM_LABELS.get(model.algorithm, model.algorithm),
        "network_label": catalog.NETWORK_LABELS.get(model.neural_network, model.neural_network),
        "hyperparameter_rows": hyperparameter_rows(model),
        "job": job,
        "jobs_ahead": services.jobs_ahead(job),
        "chart_points": points,
        "clean_streak": selectors.clean_streak(points),
        "can_start": actions.can_train,
        "can_evaluate": actions.can_evaluate,
        "can_clone": actions.can_clone,
        "can_edit_reward": actions.can_edit_reward,
        "evaluations": evaluations,
        "evaluation": evaluations[0] if evaluations else None,
        "evaluate_form": evaluate_form,
        **readiness_context(model),
    }
    return render(request, "models/detail.html", context, status=status)


@login_required
@require_http_methods(["GET", "HEAD"])
def model_detail(request: HttpRequest, model_id: int) -> HttpResponse:
    return _page(request, owned_model(request, model_id))


@login_required
@require_POST
def training_start(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    try:
        job = services.training_start(model=model, user=request.user)
    except services.ServiceError as exc:
        messages.error(request, exc.sentence)
    else:
        say_queued(request, job, "Training queued: it starts as soon as a worker is free.")
    return redirect("model-detail", model_id=model.pk)


@login_required
@require_POST
def training_stop(request: HttpRequest, job_id: int) -> HttpResponse:
    job = owned_training_job(request, job_id)
    attempt(request, lambda: services.job_stop(job=job, user=request.user),
            success="Stopping: the model keeps its last checkpoint.")  # fmt: skip
    return redirect("model-detail", model_id=job.model_id)


@login_required
@require_POST
def evaluation_start(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    form = EvaluateForm(request.POST)
    if form.is_valid():
        data = form.cleaned_data
        job, _ = attempt_on_form(
            form,
            lambda: services.evaluation_start(
                model=model,
                user=request.user,
                track_id=data["track_id"],
                direction=data["direction"],
                race_type=data["race_type"] or None,
                race_config=data["race_config"],
                laps=data["laps"],
                off_track_penalty_s=data["off_track_penalty_s"],
                crash_penalty_s=data["crash_penalty_s"],
            ),
        )
        if job is not None:
            say_queued(request, job, "Evaluation queued.")
            return redirect(f"/models/{model.pk}/#evaluation")
    return _page(request, model, evaluate_form=form, status=400)


@login_required
@require_POST
def evaluation_stop(request: HttpRequest, evaluation_id: int) -> HttpResponse:
    evaluation = owned_evaluation(request, evaluation_id)
    attempt(request, lambda: services.job_stop(job=evaluation, user=request.user))
    return redirect(f"/models/{evaluation.model_id}/#evaluation")
