"""Reads: what the web console and the command line show, always scoped to one owner.

Every lookup of a model or a job by id goes through here and filters by the owner, so a user
who asks for someone else's object gets exactly what they get for a missing one:
``DoesNotExist`` (the views turn it into a 404, the websocket consumers into a refusal).
"""

from __future__ import annotations

from dataclasses import dataclass

from django.contrib.auth import get_user_model
from django.db.models import QuerySet

from training.errors import ServiceError
from training.models import (
    ACTIVE_JOB_STATUSES,
    EvaluationJob,
    IterationMetric,
    JobStatus,
    RacingModel,
    TrainingJob,
)


def models_for_owner(owner) -> QuerySet[RacingModel]:
    """The owner's models, newest first."""
    return RacingModel.objects.filter(owner=owner).order_by("-created_at")


def model_for_owner(owner, model_id: int) -> RacingModel:
    """Raises RacingModel.DoesNotExist unless ``owner`` owns the model."""
    return RacingModel.objects.get(pk=model_id, owner=owner)


def training_job_for_owner(owner, job_id: int) -> TrainingJob:
    """Raises TrainingJob.DoesNotExist unless the job's model belongs to ``owner``."""
    return TrainingJob.objects.select_related("model").get(pk=job_id, model__owner=owner)


def evaluation_for_owner(owner, evaluation_id: int) -> EvaluationJob:
    """Raises EvaluationJob.DoesNotExist unless the evaluation's model belongs to ``owner``."""
    return EvaluationJob.objects.select_related("model").get(pk=evaluation_id, model__owner=owner)


def job_for_owner(owner, kind: str, job_id: int) -> TrainingJob | EvaluationJob:
    """A training or evaluation job (``kind``) of the owner; DoesNotExist otherwise."""
    if kind == "training":
        return training_job_for_owner(owner, job_id)
    if kind == "evaluation":
        return evaluation_for_owner(owner, job_id)
    raise TrainingJob.DoesNotExist(f"no job kind {kind!r}")


def latest_training_job(model: RacingModel) -> TrainingJob | None:
    return model.training_jobs.order_by("-created_at", "-pk").first()


def evaluations_of(model: RacingModel, limit: int = 10) -> list[EvaluationJob]:
    """The model's user evaluations, newest first; each has ``number``: 1 for the model's
    first evaluation, 2 for the next (the ids are global, shared by every model)."""
    mine = model.evaluations.filter(purpose="user")
    total = mine.count()
    rows = list(mine.order_by("-created_at", "-pk")[:limit])
    for i, evaluation in enumerate(rows):
        evaluation.number = total - i
    return rows


def chart_points(job: TrainingJob) -> list[dict]:
    """The reward graph so far: one ``IterationMetric.as_point()`` per iteration."""
    return [m.as_point() for m in IterationMetric.objects.filter(job=job).order_by("iteration")]


def clean_streak(points: list[dict]) -> int:
    """How many of the latest iterations in a row had an evaluation at 100 % (every lap
    complete): the count that "stop when ready" (``TrainingJob.stop_when_ready``) stops at."""
    streak = 0
    for point in reversed(points):
        if point["eval_progress"] < 100.0:
            break
        streak += 1
    return streak


@dataclass(frozen=True)
class ModelActions:
    """What the owner may do with a model now (the services enforce the same rules)."""

    can_train: bool
    can_evaluate: bool
    can_clone: bool
    can_edit_reward: bool = False


def model_actions(model: RacingModel, job: TrainingJob | None = None) -> ModelActions:
    """The buttons a model's page offers; ``job`` is its latest training job, if known."""
    job = job if job is not None else latest_training_job(model)
    trained = job is not None and job.status == JobStatus.COMPLETED
    busy = model.is_busy or (job is not None and job.status in ACTIVE_JOB_STATUSES)
    return ModelActions(
        can_train=not busy and not trained,
        can_evaluate=model.has_checkpoint and not model.is_busy,
        # With a checkpoint a clone continues from it (even while training goes on); without
        # one it is a fresh copy of the configuration, once the model is not busy.
        can_clone=model.has_checkpoint or not busy,
        can_edit_reward=job is None and not model.has_checkpoint and not busy,
    )


# ------------------------------------------------------------------------------ command line
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
