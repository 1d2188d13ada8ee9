"""Reads the web console needs, always scoped to one owner.

Every lookup of a model or a job by id goes through here and filters by the owner, so a user
who asks for someone else's object gets exactly what they get for a missing one:
``DoesNotExist`` (the views turn it into a 404, the websocket consumers into a refusal).
"""

from __future__ import annotations

from django.db.models import QuerySet

from training.models import EvaluationJob, IterationMetric, RacingModel, TrainingJob


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
    """The model's user evaluations, newest first."""
    return list(model.evaluations.filter(purpose="user").order_by("-created_at", "-pk")[:limit])


def chart_points(job: TrainingJob) -> list[dict]:
    """The reward graph so far: one ``IterationMetric.as_point()`` per iteration."""
    return [m.as_point() for m in IterationMetric.objects.filter(job=job).order_by("iteration")]
