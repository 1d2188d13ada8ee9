"""What a running job records besides its status goes through services: the model has a
checkpoint, an evaluation's logs sit under a stamp. (Alice owns the model.)"""

from __future__ import annotations

import pytest

from tests.training.services.factory import create
from training import services
from training.models import EvaluationJob, JobStatus, RacingModel

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


def test_a_model_marked_as_having_a_checkpoint_keeps_it(alice):
    model = create(alice)
    assert not model.has_checkpoint
    services.model_mark_checkpoint(model=model)
    assert model.has_checkpoint
    assert RacingModel.objects.get(pk=model.pk).has_checkpoint
    services.model_mark_checkpoint(model=model)  # again: nothing changes
    assert RacingModel.objects.get(pk=model.pk).has_checkpoint


def test_an_evaluation_records_where_its_logs_are(alice):
    model = create(alice)
    job = EvaluationJob.objects.create(
        model=model, track_id="racecraft_oval", status=JobStatus.IN_PROGRESS
    )
    services.evaluation_record_logs(job=job, stamp="20261125190000")
    assert job.log_stamp == "20261125190000"
    assert EvaluationJob.objects.get(pk=job.pk).log_stamp == "20261125190000"
    assert EvaluationJob.objects.get(pk=job.pk).status == JobStatus.IN_PROGRESS
