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
    form: Form, call: Callable[[], T | rewards.RewardCheck]
) -> tuple[T | None, list[dict], str]:
    """:func:`attempt_on_form` for a call that saves a reward function (``reward_check=
    "passed"``), which answers a :class:`~training.services.rewards.RewardCheck` when it saved
    nothing: a validation queued on a worker gives its poll URL as the third item (the page
    shows the progress and posts the form again when it passes); a refused function its
    errors on the form. The web process never runs the function."""
    result, reward_errors = attempt_on_form(form, call)
    if not isinstance(result, rewards.RewardCheck):
        return result, reward_errors, ""
    if result.status is rewards.RewardStatus.NEEDS_VALIDATION:
        return None, [], f"{reverse('reward-validate')}?id={result.task_id}"
    if result.error is not None:
        _show_refusal(form, result.error)
    return None, result.errors, ""


def attempt_on_form(form: Form, call: Callable[[], T]) -> tuple[T | None, list[dict]]:
    """Run ``call`` for a bound ``form``; a refusal is shown on the field it names. Returns
    the result (None when refused) and the reward function's errors for the editor."""
    try:
        return call(), []
    except ServiceError as exc:
        _show_refusal(form, exc)
        return None, exc.errors if isinstance(exc, RewardRejected) else []


def _show_refusal(form: Form, exc: ServiceError) -> None:
    if isinstance(exc, RewardRejected):
        add_service_error(form, "The reward function has errors; see the marked lines.", exc.field)
    else:
        add_service_error(form, exc.message, exc.field)
