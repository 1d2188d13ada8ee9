"""Calling a service from a view: a refusal becomes an error message on the next page, or an
error on the form field it names; success a confirmation."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from django.contrib import messages
from django.forms import Form
from django.http import HttpRequest

from console.forms import add_service_error
from training.services import RewardRejected, ServiceError

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
