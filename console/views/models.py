"""The models list and the model life: create, clone, import, delete.

Create, clone and reward edit save a reward function only after a passed validation on a
worker (``reward_check="passed"``, training/services/models.py): when one is needed the page
comes back 202 with the form as posted and the validation's poll URL (``pending_poll``);
static/js/reward_editor.js shows the progress and posts the form again once it passes."""

from __future__ import annotations

from django.conf import settings
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.urls import reverse
from django.views.decorators.debug import sensitive_post_parameters, sensitive_variables
from django.views.decorators.http import require_http_methods, require_safe
from django_ratelimit.core import is_ratelimited

from console import tracks
from console.forms import BucketImportForm, CloneForm, ImportForm, RewardForm
from console.model_form import HP_FIELDS, PPO_ONLY, SAC_ONLY, ModelCreateForm
from console.views.owned import owned_model
from console.views.service_calls import attempt_on_form, attempt_validated
from training import catalog, selectors, services
from training.services import background, bucket_imports


@login_required
@require_safe
def model_list(request: HttpRequest) -> HttpResponse:
    models = list(selectors.models_for_owner(request.user))
    names = {r.info.id: r.info.name for r in tracks.track_rows()}
    for model in models:
        model.track_name = names.get(model.track_id, model.track_id)
    return render(request, "models/list.html", {"nav": "models", "models": models})


def _editor_context(reward_errors: list[dict] | None = None) -> dict:
    return {
        "examples": [(e.id, e.title, e.race_type) for e in catalog.EXAMPLES],
        "example_sources": {e.id: catalog.example_source(e.id) for e in catalog.EXAMPLES},
        "reward_errors": reward_errors or [],
        "track_rows": tracks.track_rows(),
    }


def _create_page(request: HttpRequest, form: ModelCreateForm, **extra: object) -> HttpResponse:
    context = {
        "nav": "models",
        "form": form,
        "hp_fields": [form[key] for key in HP_FIELDS],
        "ppo_only": PPO_ONLY,
        "sac_only": SAC_ONLY,
        "rows": [
            (steer, speed, form.row_errors.get(i, ""))
            for i, (steer, speed) in enumerate(form.action_rows)
        ],
        **_editor_context(extra.pop("reward_errors", None)),  # type: ignore[arg-type]
        **extra,
    }
    return render(request, "models/create.html", context, status=_status(form, context))


def _status(form, context: dict) -> int:
    """400 for a refused form, 202 while its reward function is being validated."""
    if form.is_bound and form.errors:
        return 400
    return 202 if context.get("pending_poll") else 200


@login_required
@require_http_methods(["GET", "POST"])
def model_create(request: HttpRequest) -> HttpResponse:
    if request.method == "GET":
        if "start_from" in request.GET:  # a link to a preset: /models/new/?start_from=racing
            return _create_page(request, ModelCreateForm.from_preset(request.GET))
        return _create_page(request, ModelCreateForm())
    if "use_preset" in request.POST:
        # "Start from": re-render with the preset's values over what was typed.
        return _create_page(request, ModelCreateForm.from_preset(request.POST), jump="step-start")
    if "generate" in request.POST:
        # The action-space generator: re-render with the generated table, everything else as typed.
        bound = ModelCreateForm(request.POST)
        rows, error = bound.generated_rows()
        form = ModelCreateForm(initial=request.POST.dict(), action_rows=rows)
        return _create_page(request, form, generate_error=error, jump="action-space")
    form = ModelCreateForm(request.POST)
    if not form.is_valid():
        return _create_page(request, form)
    data = form.cleaned_data
    model, reward_errors, poll = attempt_validated(
        form,
        lambda: services.model_create(
            owner=request.user,
            name=data["name"],
            description=data["description"],
            track_id=data["track_id"],
            direction=data["direction"],
            extra_tracks=data.get("extra_tracks", []),
            race_type=data["race_type"],
            race_config=data["race_config"],
            sensors=data["sensors"],
            action_space=data["actions"],
            algorithm=data["algorithm"],
            neural_network=data["neural_network"],
            hyperparameters=data["hyperparameters"],
            reward_function=data["reward_function"],
            max_minutes=data["max_minutes"],
            stop_when_ready=data.get("stop_when_ready") or 0,
            conditions=data.get("conditions"),
            reward_check="passed",
        ),
    )
    if model is None:
        # Refused by the server, or validating: reopen the page at the reward editor when
        # that is the cause.
        jump = "step-reward" if reward_errors or poll else ""
        return _create_page(request, form, reward_errors=reward_errors, jump=jump,
                            pending_poll=poll)  # fmt: skip
    messages.success(request, f"Model {model.name} created. Start training when you are ready.")
    return redirect("model-detail", model_id=model.pk)


@login_required
@require_http_methods(["GET", "POST"])
def model_clone(request: HttpRequest, model_id: int) -> HttpResponse:
    source = owned_model(request, model_id)
    initial = {
        "name": f"{source.name}-clone"[:64],
        "description": source.description,
        "track_id": source.track_id,
        "direction": source.direction,
        "reward_function": source.reward_function,
        "max_minutes": source.max_minutes,
        "stop_when_ready": source.stop_when_ready,
    }
    form = CloneForm(request.POST or None, initial=initial)
    reward_errors: list[dict] = []
    poll = ""
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        clone, reward_errors, poll = attempt_validated(
            form,
            lambda: services.model_clone(
                model=source,
                owner=request.user,
                name=data["name"],
                description=data["description"],
                track_id=data["track_id"],
                direction=data["direction"],
                reward_function=data["reward_function"],
                max_minutes=data["max_minutes"],
                stop_when_ready=data.get("stop_when_ready") or 0,
                reward_check="passed",
            ),
        )
        if clone is not None:
            messages.success(request, f"Model {clone.name} cloned from {source.name}.")
            return redirect("model-detail", model_id=clone.pk)
    context = {
        "nav": "models",
        "form": form,
        "source": source,
        "fresh_copy": not source.has_checkpoint,
        "pending_poll": poll,
        **_editor_context(reward_errors),
    }
    return render(request, "models/clone.html", context, status=_status(form, context))


@login_required
@require_http_methods(["GET", "POST"])
def model_reward_edit(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    form = RewardForm(request.POST or None, initial={"reward_function": model.reward_function})
    reward_errors: list[dict] = []
    poll = ""
    if request.method == "POST" and form.is_valid():
        source = form.cleaned_data["reward_function"]
        updated, reward_errors, poll = attempt_validated(
            form,
            lambda: services.model_update_reward(
                model=model, user=request.user, reward_function=source, reward_check="passed"
            ),
        )
        if updated is not None:
            messages.success(request, "Reward function saved.")
            return redirect("model-detail", model_id=model.pk)
    context = {
        "nav": "models",
        "form": form,
        "model": model,
        "can_edit": selectors.model_actions(model).can_edit_reward,
        "pending_poll": poll,
        **_editor_context(reward_errors),
    }
    return render(request, "models/reward_edit.html", context, status=_status(form, context))


@login_required
@require_http_methods(["GET", "POST"])
def model_import(request: HttpRequest) -> HttpResponse:
    """The upload is stored and imported by a worker (training/services/background.py); the
    page (``?task=<id>``) shows the progress and moves on to the model when it is there."""
    form = ImportForm(request.POST or None, request.FILES or None)
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        task_id, _ = attempt_on_form(
            form,
            lambda: background.model_import_start(
                owner=request.user,
                name=data["name"],
                description=data["description"],
                data=data["archive"].read(),
            ),
        )
        if task_id is not None:
            return redirect(f"{reverse('model-import')}?task={task_id}")
    return _import_page(request, form, BucketImportForm())


@login_required
@require_http_methods(["POST"])
@sensitive_post_parameters("access_key", "secret_key")
@sensitive_variables()
def model_import_bucket(request: HttpRequest) -> HttpResponse:
    """The model is read from the DeepRacer-for-Cloud bucket in this request (bounded by the
    import's size limits and short timeouts), stored as an upload is, and imported by a worker
    the same way (training/services/bucket_imports.py). The keys live only in this request:
    never stored, queued or logged, and hidden from Django's error reports."""
    form = BucketImportForm(request.POST)
    if bucket_imports_limited(request):
        form.is_valid()  # the fields as posted, shown again
        form.add_error(None, TOO_MANY_BUCKET_IMPORTS)
        return _import_page(request, ImportForm(), form, status=429)
    if form.is_valid():
        task_id, _ = attempt_on_form(
            form,
            lambda: bucket_imports.model_import_from_bucket_start(
                owner=request.user, **form.cleaned_data
            ),
        )
        if task_id is not None:
            return redirect(f"{reverse('model-import')}?task={task_id}")
    return _import_page(request, ImportForm(), form)


TOO_MANY_BUCKET_IMPORTS = "Too many imports from a bucket; wait a while and try again."


def bucket_imports_limited(request: HttpRequest) -> bool:
    """Whether this user posted more bucket imports than RACECRAFT_BUCKET_IMPORT_RATE (each
    makes the server read a remote server: not a thing to do in a loop)."""
    return is_ratelimited(request, group="bucket-import", key="user",
                          rate=settings.RACECRAFT_BUCKET_IMPORT_RATE, method="POST",
                          increment=True)  # fmt: skip


def _import_page(
    request: HttpRequest,
    form: ImportForm,
    bucket_form: BucketImportForm,
    status: int | None = None,
) -> HttpResponse:
    task = request.GET.get("task", "")
    poll = reverse("background-task", args=[task]) if task.isalnum() else ""
    bound = [f for f in (form, bucket_form) if f.is_bound]
    status = status or (400 if any(f.errors for f in bound) else 200)
    context = {"nav": "models", "form": form, "bucket_form": bucket_form, "task_poll": poll}
    return render(request, "models/import.html", context, status=status)


@login_required
@require_http_methods(["GET", "POST"])
def model_delete(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    error = ""
    if request.method == "POST":
        try:
            services.model_delete(model=model, user=request.user)
        except services.ServiceError as exc:
            error = exc.message
        else:
            messages.success(request, f"Model {model.name} deleted.")
            return redirect("models")
    return render(
        request,
        "models/delete.html",
        {"nav": "models", "model": model, "error": error},
        status=409 if error else 200,
    )
