"""Owner-scoped lookups for views: someone else's object is a 404, like a missing one."""

from __future__ import annotations

from django.contrib import messages
from django.http import Http404, HttpRequest

from training import selectors
from training.models import EvaluationJob, RacingModel, TrainingJob


def owned_model(request: HttpRequest, model_id: int) -> RacingModel:
    try:
        return selectors.model_for_owner(request.user, model_id)
    except RacingModel.DoesNotExist:
        raise Http404("No such model") from None


def owned_training_job(request: HttpRequest, job_id: int) -> TrainingJob:
    try:
        return selectors.training_job_for_owner(request.user, job_id)
    except TrainingJob.DoesNotExist:
        raise Http404("No such training job") from None


def owned_evaluation(request: HttpRequest, evaluation_id: int) -> EvaluationJob:
    try:
        return selectors.evaluation_for_owner(request.user, evaluation_id)
    except EvaluationJob.DoesNotExist:
        raise Http404("No such evaluation") from None


def say_queued(request: HttpRequest, job: object, success: str) -> None:
    """The confirmation, or, when the task queue could not be reached, that the job waits."""
    note = getattr(job, "dispatch_note", "")
    if note:
        messages.warning(request, f"{success.split(':')[0].rstrip('.')}, but {note}.")
    else:
        messages.success(request, success)
