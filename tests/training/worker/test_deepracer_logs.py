"""A real training and evaluation, read back by the community's own reader, ``deepracer-utils``:
from the model's folder in an S3 store (moto's server on loopback, through the MinIO backend),
from the logs archive extracted, and from the logs download as it is (no extraction) through
``TarFileHandler``. Episode counts, per-episode times, iterations and evaluation laps must be
what the job recorded in the database, and the reader's stability and real-time-factor analysis
must find real wall-clock times. (One training serves every reader: it is the costly part.)"""

from __future__ import annotations

import io
import math
import os
import tarfile
import uuid
from collections.abc import Iterator

import numpy as np
import pytest
from django.contrib.auth import get_user_model
from moto.server import ThreadedMotoServer

from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from tests.support import train_in_thread
from training import services
from training.models import EpisodeMetric, EvaluationJob
from training.services import downloads
from training.worker.evaluation import run_evaluation_job

pytest.importorskip("deepracer.logs")
from deepracer.logs import (  # noqa: E402 - only once the reader is known to be installed
    AnalysisUtils,
    DeepRacerLog,
    LogFolderType,
    S3FileHandler,
    TarFileHandler,
    TrainingMetrics,
)

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]
ACCESS, SECRET = "racecraft-test", "racecraft-test-secret"
EPISODES_PER_ITERATION = 4


@pytest.fixture
def s3(settings) -> Iterator[tuple[str, str]]:
    """A moto S3 server on loopback as the store: ``(endpoint URL, bucket)``."""
    names = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_DEFAULT_REGION")
    saved = {k: os.environ.get(k) for k in names}
    os.environ.update(dict(zip(names, (ACCESS, SECRET, "us-east-1"), strict=True)))
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    bucket = f"deepracer-logs-{uuid.uuid4().hex[:8]}"
    settings.MINIO_ENDPOINT, settings.MINIO_BUCKET = f"{host}:{port}", bucket
    settings.MINIO_ACCESS_KEY, settings.MINIO_SECRET_KEY = ACCESS, SECRET
    settings.MINIO_SECURE = False
    try:
        yield f"http://{host}:{port}", bucket
    finally:
        server.stop()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def test_deepracer_utils_reads_what_the_job_recorded(s3, tmp_path) -> None:
    endpoint, bucket = s3
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    model = services.model_create(
        owner=alice, name="log-reader", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function=REWARD, max_minutes=5, seed=3,
        hyperparameters={"num_episodes_between_training": EPISODES_PER_ITERATION,
                         "num_epochs": 3, "batch_size": 32},
    )  # fmt: skip
    assert model.store_prefix == f"u{alice.pk}-log-reader"
    job = services.training_start(model=model, user=alice, enqueue=False)
    job = train_in_thread(job, alice, iterations=2, within_s=400)
    assert job.status == "COMPLETED", job.error
    evaluation = services.evaluation_start(model=model, user=alice, laps=3, enqueue=False)
    assert run_evaluation_job(evaluation.pk, "test") == "completed"
    evaluation = EvaluationJob.objects.get(pk=evaluation.pk)
    assert len(evaluation.log_stamp) == 14

    rows = EpisodeMetric.objects.filter(job=job)
    training = list(rows.filter(phase="training").order_by("episode"))
    assert job.episodes == len(training) >= EPISODES_PER_ITERATION
    per_iteration = np.bincount([r.iteration for r in training])[1:]
    assert list(per_iteration[:-1]) == [EPISODES_PER_ITERATION] * (len(per_iteration) - 1)

    # The model's folder in the S3 store, as DeepRacer-for-Cloud users point the reader at it.
    handler = S3FileHandler(bucket=bucket, prefix=model.store_prefix, s3_endpoint_url=endpoint)
    log = DeepRacerLog(filehandler=handler)
    log.load_training_trace()
    _check_training_trace(log.dataframe(), training)
    metrics = TrainingMetrics(bucket, model_name=model.store_prefix, s3_endpoint_url=endpoint)
    _check_training_metrics(metrics, training, rows.filter(phase="evaluation").count())
    log.load_evaluation_trace(force=True)
    _check_evaluation(log.dataframe(), evaluation)

    # The logs archive, extracted: the model's folder, in the console's layout.
    archive = downloads.logs_archive(model)
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(tmp_path / "logs", filter="data")
    local = DeepRacerLog(model_folder=str(tmp_path / "logs" / model.store_folder))
    local.load_training_trace()
    _check_training_trace(local.dataframe(), training)
    local.load_evaluation_trace(force=True)
    _check_evaluation(local.dataframe(), evaluation)

    # The logs download as the browser saves it, read as it is by TarFileHandler.
    path = tmp_path / f"{model.name}-logs.tar.gz"
    path.write_bytes(archive)
    _check_logs_download(path, training, evaluation)


def _check_logs_download(path, training: list[EpisodeMetric], evaluation: EvaluationJob) -> None:
    handler = TarFileHandler(str(path))
    log = DeepRacerLog(filehandler=handler)
    assert handler.type is LogFolderType.DROA_SOLUTION_LOGS

    log.load_training_trace()
    df = log.dataframe()
    _check_training_trace(df, training)
    for _, episode in df.groupby("unique_episode"):
        wall = episode.sort_values("steps")["wall_clock"].to_numpy()
        assert (np.diff(wall) > 0).all() and wall[0] > 1.7e9
    assert df["pause_duration"].notna().all() and (df["pause_duration"] >= 0).all()

    stats = log.stability.analyze()
    assert len(stats) == df["iteration"].nunique()
    assert all(math.isfinite(v) and v > 0 for v in stats["rtf"])
    assert all(math.isfinite(v) and v > 0 for v in stats["avg_ms"])
    assert all(math.isfinite(v) and v > 0 for v in stats["train_time_s"])

    log.load_evaluation_trace(force=True)
    df = log.dataframe()
    assert list(df["stream"].unique()) == [evaluation.log_stamp]
    _check_evaluation(df, evaluation)
    (rtf,) = log.stability.analyze()["rtf"]
    assert math.isfinite(rtf) and rtf > 0


def _check_training_trace(df, training: list[EpisodeMetric]) -> None:
    assert df["unique_episode"].nunique() == len(training)
    assert df["iteration"].nunique() == len({r.iteration for r in training})
    agg = AnalysisUtils.simulation_agg(df, secondgroup="unique_episode")
    times = dict(zip(agg["unique_episode"], agg["time"], strict=True))
    for row in training:
        assert times[row.episode - 1] == pytest.approx(row.elapsed_time_in_milliseconds / 1000,
                                                       abs=0.002)  # fmt: skip
    assert (agg["time"] > 0).all()


def _check_training_metrics(metrics, training: list[EpisodeMetric], evaluations: int) -> None:
    df = metrics.metrics
    assert len(metrics.getTraining()) == len(training)
    assert len(metrics.getEvaluation()) == evaluations > 0
    assert df["iteration"].max() + 1 == len({r.iteration for r in training})
    summary = metrics.getSummary()
    counts = np.bincount([r.iteration for r in training])[1:]
    assert list(summary["train_episodes"]) == list(counts)
    recorded = [r.elapsed_time_in_milliseconds / 1000 for r in training]
    assert list(metrics.getTraining()["time"]) == pytest.approx(recorded)


def _check_evaluation(df, evaluation: EvaluationJob) -> None:
    laps = evaluation.lap_rows
    assert df["episode"].nunique() == len(laps)
    agg = AnalysisUtils.simulation_agg(df, firstgroup="stream", is_eval=True)
    assert list(agg["time"]) == pytest.approx([lap["time_s"] for lap in laps], abs=0.002)
    assert list(agg["progress"]) == pytest.approx([lap["progress"] for lap in laps], abs=0.01)
