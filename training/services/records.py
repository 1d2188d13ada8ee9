"""What a running job records as it goes, besides its status (:mod:`training.services.jobs`):
the model has a checkpoint now, an evaluation's logs are in the store under a stamp. The
worker calls these; it never writes a model's or a job's row itself."""

from __future__ import annotations

from training.models import EvaluationJob, RacingModel


def model_mark_checkpoint(*, model: RacingModel) -> None:
    """``model`` has a checkpoint in the store (written by its training job): from now on it
    can be evaluated, and a job that ends leaves it READY. Idempotent."""
    if not model.has_checkpoint:
        RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
        model.has_checkpoint = True


def evaluation_record_logs(*, job: EvaluationJob, stamp: str) -> None:
    """The evaluation's metrics and sim-trace are in the store under ``stamp``
    (``interchange.layout.evaluation_stamp``: 14 digits, the job's start time)."""
    EvaluationJob.objects.filter(pk=job.pk).update(log_stamp=stamp)
    job.log_stamp = stamp
