"""A training job of an object-avoidance model with stereo cameras and a LIDAR, run by the real
job code (sandboxed rollout workers, the store, the metrics rows), then its evaluation job in
the model's race and its car download with both inputs named as DeepRacer names them."""

from __future__ import annotations

import io
import json
import tarfile

import pytest
from django.contrib.auth import get_user_model

from tests.support import train_in_thread
from training import services
from training.interchange.carmodel import input_name
from training.interchange.tfgraph import parse_graph
from training.models import EvaluationJob, JobStatus
from training.services import downloads
from training.store import get_store, keys_for
from training.worker.evaluation import run_evaluation_job

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow,
              pytest.mark.usefixtures("store_dir")]  # fmt: skip
ACTIONS = [{"steering_angle": a, "speed": 0.8} for a in (-30, 0, 30)]
REWARD = """
def reward_function(params):
    if params["is_crashed"] or not params["all_wheels_on_track"]:
        return 1e-3
    return 1.0
"""


def test_an_object_avoidance_lidar_model_trains_evaluates_and_downloads():
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    model = services.model_create(
        owner=alice, name="box-dodger", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function=REWARD, max_minutes=10, seed=3, race_type="OBJECT_AVOIDANCE",
        race_config={"number_of_objects": 2}, sensors=["STEREO_CAMERAS", "LIDAR"],
        hyperparameters={"num_episodes_between_training": 4, "num_epochs": 3,
                         "batch_size": 32},
    )  # fmt: skip
    job = services.training_start(model=model, user=alice, enqueue=False)
    job = train_in_thread(job, alice, iterations=1, within_s=500)
    assert job.status == JobStatus.COMPLETED and job.iterations >= 1, job.error
    model.refresh_from_db()
    assert model.has_checkpoint
    store, keys = get_store(), keys_for(model.pk)
    metadata = json.loads(store.get_bytes(keys.metadata))
    assert metadata["sensor"] == ["STEREO_CAMERAS", "LIDAR"]

    evaluation = services.evaluation_start(model=model, user=alice, laps=3, enqueue=False)
    assert run_evaluation_job(evaluation.pk, "test") == "completed"
    evaluation = EvaluationJob.objects.get(pk=evaluation.pk)
    assert evaluation.race_type == "OBJECT_AVOIDANCE" and evaluation.lap_rows
    assert {"crashes", "crash_penalty_s", "resets"} <= set(evaluation.lap_rows[0])
    assert evaluation.has_video

    car = downloads.car_model_archive(model)
    with tarfile.open(fileobj=io.BytesIO(car)) as tar:
        graph = parse_graph(tar.extractfile("agent/model.pb").read())
        car_metadata = json.loads(tar.extractfile("model_metadata.json").read())
    assert car_metadata["sensor"] == ["STEREO_CAMERAS", "LIDAR"]
    inputs = {n.name for n in graph.node if n.op == "Placeholder"}
    assert inputs == {input_name("clipped_ppo", "STEREO_CAMERAS"),
                      input_name("clipped_ppo", "LIDAR")}  # fmt: skip
