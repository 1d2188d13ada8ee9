"""A whole model life through a real Celery worker, Redis and the model store: train (stopped
by the user), evaluate, clone, export for the car (checked with onnxruntime), delete."""

from __future__ import annotations

import io
import json
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest
from django.contrib.auth import get_user_model

from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from tests.support import ChildProcess
from training import services
from training.models import EvaluationJob, IterationMetric, JobStatus, RacingModel, TrainingJob
from training.services import downloads
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]


def wait_for(predicate, timeout: float, what: str, log_path: Path | None = None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    extra = log_path.read_text()[-4000:] if log_path and log_path.exists() else ""
    pytest.fail(f"timed out waiting for {what}\n{extra}")


def test_train_stop_evaluate_clone_export_delete(celery_worker: ChildProcess, store_dir):
    User = get_user_model()
    alice = User.objects.create_user("alice", password="pw-alice-123")
    bob = User.objects.create_user("bob", password="pw-bob-123")
    log_path = celery_worker.log_path
    model = services.model_create(
        owner=alice,
        name="oval-runner",
        track_id="racecraft_oval",
        action_space=ACTIONS,
        reward_function=REWARD,
        hyperparameters={
            "num_episodes_between_training": 4,
            "num_epochs": 3,
            "batch_size": 32,
        },  # fmt: skip
        max_minutes=30,  # ended by the stop below, never by the time limit
        seed=1,
    )
    job = services.training_start(model=model, user=alice)
    with pytest.raises(services.ServiceError):
        services.job_stop(job=job, user=bob)  # Bob cannot touch Alice's job

    wait_for(lambda: TrainingJob.objects.get(pk=job.pk).iterations >= 2, 900,
             "two training iterations", log_path)  # fmt: skip
    services.job_stop(job=TrainingJob.objects.get(pk=job.pk), user=alice)
    job = wait_for(
        lambda: TrainingJob.objects.filter(pk=job.pk, status=JobStatus.COMPLETED).first(),
        120, "the stopped job to complete", log_path,
    )  # fmt: skip
    assert job.stopped_by == "user"
    model.refresh_from_db()
    assert model.status == RacingModel.Status.READY and model.has_checkpoint

    points = list(IterationMetric.objects.filter(job=job).order_by("iteration"))
    assert len(points) >= 2 and points[0].iteration == 1
    assert all(0 <= p.eval_progress <= 100 for p in points)
    assert sum(p.is_best for p in points) >= 1
    assert job.episodes > 0 and job.episode_metrics.filter(phase="training").count() == job.episodes

    store, keys = get_store(), keys_for(model.pk)
    for key in (keys.best, keys.last, keys.metadata, keys.hyperparameters, keys.reward_function,
                keys.training_metrics, keys.simtrace(0), keys.car_export):  # fmt: skip
        assert store.exists(key), key
    csv = store.get_bytes(keys.simtrace(0)).decode().splitlines()
    assert csv[0].split(",")[:3] == ["episode", "steps", "X"] and len(csv[0].split(",")) == 19
    assert len(csv) > 10
    metrics = json.loads(store.get_bytes(keys.training_metrics))
    training = [m for m in metrics["metrics"] if m["phase"] == "training"]
    assert metrics["version"] == 2 and len(training) == job.episodes

    evaluation = services.evaluation_start(model=model, user=alice, laps=3)
    evaluation = wait_for(
        lambda: EvaluationJob.objects.filter(pk=evaluation.pk, status=JobStatus.COMPLETED).first(),
        240, "the evaluation", log_path,
    )  # fmt: skip
    laps = evaluation.lap_rows
    assert 1 <= len(laps) <= 3
    assert {"trial", "time_s", "progress", "status", "off_tracks", "resets"} <= set(laps[0])
    video = downloads.evaluation_video(evaluation)
    assert evaluation.has_video and video.size > 8 and video.read(4, 4) == b"ftyp"
    assert store.exists(keys.evaluation_metrics(evaluation.log_stamp))
    assert store.exists(keys.evaluation_simtrace(evaluation.log_stamp))

    clone = services.model_clone(model=model, owner=alice, name="oval-runner-2")
    assert clone.parent == model and clone.has_checkpoint
    assert store.get_bytes(keys_for(clone.pk).checkpoint("initial")) == store.get_bytes(keys.best)

    car = downloads.car_model_archive(model)
    with tarfile.open(fileobj=io.BytesIO(car)) as tar:
        names = set(tar.getnames())
    # What the car's loader needs: exactly one .pb, and the metadata at the archive's root.
    assert [n for n in names if n.endswith(".pb")] == ["agent/model.pb"]
    assert "model_metadata.json" in names
    _onnx_agrees_with_torch(model, downloads.onnx_policy(model))

    logs = downloads.logs_archive(model)
    with tarfile.open(fileobj=io.BytesIO(logs)) as tar:
        assert any(n.startswith(f"{model.store_folder}/sim-trace/training/")
                   for n in tar.getnames())  # fmt: skip

    services.model_delete(model=clone, user=alice)
    assert not store.list(keys_for(clone.pk).prefix)
    assert not RacingModel.objects.filter(pk=clone.pk).exists()


def _onnx_agrees_with_torch(model: RacingModel, onnx_bytes: bytes) -> None:
    import onnxruntime as ort

    from racing.env import RacingEnv
    from training.rl.checkpoints import load_checkpoint
    from training.services import model_metadata

    policy = load_checkpoint(get_store().get_bytes(keys_for(model.pk).best), model_metadata(model))
    session = ort.InferenceSession(onnx_bytes, providers=["CPUExecutionProvider"])
    env = RacingEnv("racecraft_oval", action_space=model.action_space)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(12):
        probs = session.run(None, {"observation": obs.transpose(2, 0, 1)[None].astype(np.float32)})
        torch_action, _ = policy.predict(obs, deterministic=True)
        assert int(np.argmax(probs[0])) == int(torch_action)
        obs, *_ = env.step(int(rng.integers(len(model.action_space))))
    env.close()
