"""Services for the command line: jobs created without queueing, so that a ``manage.py``
command can run them in its own process (no Celery worker), and lookups by name and id.

The checks mirror :func:`training.services.training_start` and
:func:`training.services.evaluation_start` (owner, busy model, already trained, job quota);
only the ``on_commit`` enqueue is missing. The caller runs the job with
:func:`training.jobs.run_training_job` / :func:`training.jobs.run_evaluation_job`.
"""

from __future__ import annotations

from django.contrib.auth import get_user_model

from training.models import EvaluationJob, RacingModel, TrainingJob
from training.services import ServiceError, evaluation_start, training_start


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


def training_create(*, model: RacingModel, user) -> TrainingJob:
    """A training job row in QUEUED, not sent to Celery: the caller runs it in-process.

    Same rules as :func:`training.services.training_start`. Raises :class:`ServiceError`.
    """
    return training_start(model=model, user=user, enqueue=False)


def evaluation_create(*, model: RacingModel, user, **settings) -> EvaluationJob:
    """An evaluation row in QUEUED, not sent to Celery: the caller runs it in-process.

    Same rules and keyword arguments as :func:`training.services.evaluation_start`.
    """
    return evaluation_start(model=model, user=user, enqueue=False, **settings)
