"""The logs download of a really trained and evaluated model, read as it is (no extraction) by
the community's own reader, ``deepracer-utils``' ``TarFileHandler``: episodes, iterations,
per-episode times and evaluation laps must be what the job recorded in the database, and the
reader's stability and real-time-factor analysis must find real wall-clock times."""

from __future__ import annotations

import math

import numpy as np
import pytest
from django.contrib.auth import get_user_model

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
    TarFileHandler,
)

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]
EPISODES_PER_ITERATION = 4


def test_tarfilehandler_reads_the_logs_download(store_dir, tmp_path) -> None:
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    model = services.model_create(
        owner=alice, name="tar-reader", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function=REWARD, max_minutes=5, seed=4,
        hyperparameters={"num_episodes_between_training": EPISODES_PER_ITERATION,
                         "num_epochs": 3, "batch_size": 32},
    )  # fmt: skip
    job = services.training_start(model=model, user=alice, enqueue=False)
    job = train_in_thread(job, alice, iterations=2, within_s=400)
    assert job.status == "COMPLETED", job.error
    evaluation = services.evaluation_start(model=model, user=alice, laps=3, enqueue=False)
    assert run_evaluation_job(evaluation.pk, "test") == "completed"
    evaluation = EvaluationJob.objects.get(pk=evaluation.pk)
    training = list(EpisodeMetric.objects.filter(job=job, phase="training").order_by("episode"))

    path = tmp_path / f"{model.name}-logs.tar.gz"  # the file the browser saves
    path.write_bytes(downloads.logs_archive(model))
    handler = TarFileHandler(str(path))
    log = DeepRacerLog(filehandler=handler)
    assert handler.type is LogFolderType.DROA_SOLUTION_LOGS

    log.load_training_trace()
    df = log.dataframe()
    assert df["unique_episode"].nunique() == len(training)
    assert df["iteration"].nunique() == len({r.iteration for r in training})
    agg = AnalysisUtils.simulation_agg(df, secondgroup="unique_episode")
    times = dict(zip(agg["unique_episode"], agg["time"], strict=True))
    for row in training:
        assert times[row.episode - 1] == pytest.approx(row.elapsed_time_in_milliseconds / 1000,
                                                       abs=0.002)  # fmt: skip
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
    laps = evaluation.lap_rows
    df = log.dataframe()
    assert list(df["stream"].unique()) == [evaluation.log_stamp]
    assert df["episode"].nunique() == len(laps)
    agg = AnalysisUtils.simulation_agg(df, firstgroup="stream", is_eval=True)
    assert list(agg["time"]) == pytest.approx([lap["time_s"] for lap in laps], abs=0.002)
    assert list(agg["progress"]) == pytest.approx([lap["progress"] for lap in laps], abs=0.01)
    (rtf,) = log.stability.analyze()["rtf"]
    assert math.isfinite(rtf) and rtf > 0
