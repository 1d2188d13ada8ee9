"""Calling a service from a view: a refusal becomes an error message on the next page, or an
error on the form field it names; success a confirmation."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from django.contrib import messages
from django.forms import Form
from django.http import HttpRequest
from django.urls import reverse

from console.forms import add_service_error
from training.services import RewardRejected, ServiceError, rewards

T = TypeVar("T")


def attempt(request: HttpRequest, call: Callable[[], object], *, success: str = "") -> bool:
    """Run ``call``; on :class:`ServiceError` show its sentence and return False."""
    try:
        call()
    except ServiceError as exc:
        messages.error(request, exc.sentence)
        return False
    if success:
        messages.success(request, success)
    return True


def attempt_validated(
    request: HttpRequest, form: Form, call: Callable[[], T]
) -> tuple[T | None, list[dict], str]:
    """:func:`attempt_on_form` for a call that saves a reward function (``reward_check=
    "passed"``): when the function still needs a validation, queue one on a worker and return
    its poll URL as the third item (the page shows the progress and posts the form again when
    it passes). The web process never runs the function."""
    try:
        return call(), [], ""
    except rewards.ValidationNeeded as exc:
        needed = exc
    except RewardRejected as exc:
        add_service_error(form, "The reward function has errors; see the marked lines.", exc.field)
        return None, exc.errors, ""
    except ServiceError as exc:
        add_service_error(form, exc.message, exc.field)
        return None, [], ""
    try:
        task_id = rewards.reward_validation_start(
            user_id=request.user.pk, source=needed.source, track_id=needed.track_id,
            direction=needed.direction,
        )  # fmt: skip
    except ServiceError as exc:
        add_service_error(form, exc.message, "reward_function")
        return None, [], ""
    return None, [], f"{reverse('reward-validate')}?id={task_id}"


def attempt_on_form(form: Form, call: Callable[[], T]) -> tuple[T | None, list[dict]]:
    """Run ``call`` for a bound ``form``; a refusal is shown on the field it names. Returns
    the result (None when refused) and the reward function's errors for the editor."""
    try:
        return call(), []
    except RewardRejected as exc:
        add_service_error(form, "The reward function has errors; see the marked lines.", exc.field)
        return None, exc.errors
    except ServiceError as exc:
        add_service_error(form, exc.message, exc.field)
        return None, []
