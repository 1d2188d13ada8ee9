"""Lookups for the command line: users by name and models by id, with messages that say what
is missing. (Jobs a command runs in its own process come from ``training.services`` with
``enqueue=False``.)"""

from __future__ import annotations

from django.contrib.auth import get_user_model

from training.models import RacingModel
from training.services import ServiceError


def user_by_username(*, username: str):
    """The user named ``username``. Raises :class:`ServiceError` when there is none."""
    User = get_user_model()
    try:
        return User.objects.get(**{User.USERNAME_FIELD: username})
    except User.DoesNotExist:
        raise ServiceError(
            f"there is no user named {username!r}; create one first "
            "(manage.py createsuperuser, or sign up in the console)"
        ) from None


def model_for_cli(*, model_id: int, user=None) -> RacingModel:
    """Model ``model_id``; when ``user`` is given it must own it. Raises :class:`ServiceError`."""
    model = RacingModel.objects.select_related("owner").filter(pk=model_id).first()
    if model is None or (user is not None and model.owner_id != user.pk):
        whose = f" owned by {user.get_username()!r}" if user is not None else ""
        raise ServiceError(f"there is no model {model_id}{whose}")
    return model
