"""The models list and the model life: create, clone, import, delete."""

from __future__ import annotations

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.views.decorators.http import require_http_methods, require_safe

from console import tracks
from console.forms import CloneForm, ImportForm, RewardForm
from console.model_form import HP_FIELDS, PPO_ONLY, SAC_ONLY, ModelCreateForm
from console.views.owned import owned_model
from console.views.service_calls import attempt_on_form
from training import selectors, services
from training.rewards.examples import EXAMPLES, example_source


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
        "examples": [(e.id, e.title, e.race_type) for e in EXAMPLES],
        "example_sources": {e.id: example_source(e.id) for e in EXAMPLES},
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
    status = 400 if form.is_bound and form.errors else 200
    return render(request, "models/create.html", context, status=status)


@login_required
@require_http_methods(["GET", "POST"])
def model_create(request: HttpRequest) -> HttpResponse:
    if request.method == "GET":
        return _create_page(request, ModelCreateForm())
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
    model, reward_errors = attempt_on_form(
        form,
        lambda: services.model_create(
            owner=request.user,
            name=data["name"],
            description=data["description"],
            track_id=data["track_id"],
            direction=data["direction"],
            race_type=data["race_type"],
            sensors=[data["sensor"]],
            action_space=data["actions"],
            algorithm=data["algorithm"],
            neural_network=data["neural_network"],
            hyperparameters=data["hyperparameters"],
            reward_function=data["reward_function"],
            max_minutes=data["max_minutes"],
        ),
    )
    if model is None:
        # Refused by the server: reopen the page at the reward editor when that is the cause.
        jump = "step-reward" if reward_errors else ""
        return _create_page(request, form, reward_errors=reward_errors, jump=jump)
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
    }
    form = CloneForm(request.POST or None, initial=initial)
    reward_errors: list[dict] = []
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        clone, reward_errors = attempt_on_form(
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
        **_editor_context(reward_errors),
    }
    status = 400 if form.is_bound and form.errors else 200
    return render(request, "models/clone.html", context, status=status)


@login_required
@require_http_methods(["GET", "POST"])
def model_reward_edit(request: HttpRequest, model_id: int) -> HttpResponse:
    model = owned_model(request, model_id)
    form = RewardForm(request.POST or None, initial={"reward_function": model.reward_function})
    reward_errors: list[dict] = []
    if request.method == "POST" and form.is_valid():
        updated, reward_errors = attempt_on_form(
            form,
            lambda: services.model_update_reward(
                model=model, user=request.user, reward_function=form.cleaned_data["reward_function"]
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
        **_editor_context(reward_errors),
    }
    status = 400 if form.is_bound and form.errors else 200
    return render(request, "models/reward_edit.html", context, status=status)


@login_required
@require_http_methods(["GET", "POST"])
def model_import(request: HttpRequest) -> HttpResponse:
    form = ImportForm(request.POST or None, request.FILES or None)
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        model, _ = attempt_on_form(
            form,
            lambda: services.model_import(
                owner=request.user,
                name=data["name"],
                description=data["description"],
                upload=data["archive"],
            ),
        )
        if model is not None:
            messages.success(request, f"Model {model.name} imported.")
            if getattr(model, "import_note", ""):
                messages.warning(request, model.import_note[:1].upper() + model.import_note[1:])
            return redirect("model-detail", model_id=model.pk)
    status = 400 if form.is_bound and form.errors else 200
    return render(request, "models/import.html", {"nav": "models", "form": form}, status=status)


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
