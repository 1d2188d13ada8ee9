"""Model and job rules: validation with clear messages, quotas, ownership, queueing failures,
stopping, and noticing jobs whose worker died. (Alice owns things; Bob must never touch them.)"""

from __future__ import annotations

import pytest
from django.utils import timezone

from tests.training.services.factory import ACTIONS, REWARD, create
from training import services
from training.models import EvaluationJob, JobStatus, RacingModel, TrainingJob
from training.services import RewardRejected, ServiceError
from training.storage import StoreError, StoreUnavailable

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


def test_create_stores_deepracer_files(alice):
    from training.store import get_store, keys_for

    model = create(alice, validate_reward=True)
    assert model.status == RacingModel.Status.READY and not model.has_checkpoint
    assert model.action_space_type == "discrete" and model.hyperparameters["batch_size"] == 64
    store, keys = get_store(), keys_for(model.pk)
    assert store.get_bytes(keys.reward_function).decode() == REWARD
    assert b'"action_space"' in store.get_bytes(keys.metadata)
    assert store.exists(keys.hyperparameters)


@pytest.mark.parametrize(
    "overrides, field, message",
    [
        ({"name": "has space"}, "name", "letters, digits or hyphens"),
        ({"name": "x" * 65}, "name", "1-64"),
        ({"track_id": "atlantis"}, "track_id", "unknown track"),
        ({"direction": "sideways"}, "direction", "native, ccw or cw"),
        ({"race_type": "F1"}, "race_type", "unknown race type"),
        (
            {"race_type": "OBJECT_AVOIDANCE", "race_config": {"number_of_objects": 7}},
            "number_of_objects",
            "1 to 6",
        ),
        (
            {"race_type": "OBJECT_AVOIDANCE", "race_config": {"object_positions": [[0.5, 2]]}},
            "object_positions",
            "1 \\(inner\\) or -1",
        ),
        ({"race_type": "HEAD_TO_BOT", "race_config": {"bot_speed": 9}}, "bot_speed", "0.2-6.0"),
        (
            {"race_type": "HEAD_TO_BOT", "race_config": {"number_of_objects": 2}},
            "race_type",
            "no setting 'number_of_objects'",
        ),
        (
            {"race_type": "TIME_TRIAL", "race_config": {"number_of_bots": 2}},
            "race_type",
            "no setting",
        ),
        ({"algorithm": "sac"}, "algorithm", "continuous"),
        ({"action_space": [{"steering_angle": 0, "speed": 1}]}, "action_space", "2-30"),
        ({"sensors": ["LIDAR"]}, "sensors", "LIDAR"),
        ({"neural_network": "HUGE"}, "neural_network", "HUGE"),
        ({"hyperparameters": {"batch_size": 100}}, "hyperparameters", "batch_size"),
        ({"hyperparameters": {"lr": 1}}, "hyperparameters", "lr"),
        ({"max_minutes": 0}, "max_minutes", "minutes"),
        ({"stop_when_ready": 21}, "stop_when_ready", "1-20 evaluations in a row"),
        ({"stop_when_ready": -1}, "stop_when_ready", "0 for the time limit alone"),
        ({"stop_when_ready": True}, "stop_when_ready", "every lap"),
        ({"stop_when_ready": "3"}, "stop_when_ready", "every lap"),
        ({"description": "d" * 256}, "description", "255"),
    ],
)
def test_bad_input_is_refused_with_a_clear_message(alice, overrides, field, message):
    with pytest.raises(ServiceError, match=message) as err:
        create(alice, **overrides)
    assert err.value.field == field
    assert not RacingModel.objects.exists()  # nothing half-made


def test_reward_errors_come_back_with_lines(alice):
    source = "import os\n\ndef reward_function(params):\n    return 1.0\n"
    with pytest.raises(RewardRejected) as err:
        create(alice, reward_function=source, validate_reward=True)
    first = err.value.errors[0]
    assert first["type"] == "IMPORT_ERROR" and first["line"] == 1
    broken = "def reward_function(params):\n    x = params['speed'\n    return x\n"
    with pytest.raises(RewardRejected) as err:
        create(alice, reward_function=broken, validate_reward=True)
    assert err.value.errors[0]["type"] == "SYNTAX_ERROR"
    runtime = "def reward_function(params):\n    return params['nope']\n"
    with pytest.raises(RewardRejected) as err:
        create(alice, reward_function=runtime, validate_reward=True)
    assert err.value.errors[0]["type"] == "TEST_FAILURE" and err.value.errors[0]["line"] == 2


def test_names_are_unique_per_owner(alice, bob):
    create(alice)
    with pytest.raises(ServiceError, match="already have a model named 'm1'"):
        create(alice)
    assert create(bob).name == "m1"  # Bob may use the same name


def test_model_quota(alice, settings):
    settings.RACECRAFT_MAX_MODELS_PER_USER = 2
    create(alice, name="a")
    create(alice, name="b")
    with pytest.raises(ServiceError, match="2 models, the most allowed"):
        create(alice, name="c")


def test_only_the_owner_can_act(alice, bob, django_capture_on_commit_callbacks):
    model = create(alice)
    for call in (
        lambda: services.training_start(model=model, user=bob),
        lambda: services.evaluation_start(model=model, user=bob),
        lambda: services.model_delete(model=model, user=bob),
        lambda: services.model_clone(model=model, owner=bob, name="mine"),
    ):
        with pytest.raises(ServiceError, match="not found"):
            call()


def test_start_queues_after_commit_and_a_broker_failure_keeps_the_job_queued(
    alice, monkeypatch, django_capture_on_commit_callbacks
):
    from training import dispatch

    model = create(alice)

    def broken(*args, **kwargs):
        raise ConnectionError("broker unreachable")

    monkeypatch.setattr(dispatch, "send", broken)
    with django_capture_on_commit_callbacks(execute=True):
        job = services.training_start(model=model, user=alice)
    assert "stays queued" in job.dispatch_note  # for the page to say
    job.refresh_from_db()
    # Kept for the reaper to send once the broker is back (tests/faults/test_broker_down.py).
    assert job.status == JobStatus.QUEUED and job.task_id == "" and job.error == ""
    model.refresh_from_db()
    assert model.status == RacingModel.Status.QUEUED


def test_job_quota_and_busy_model(alice, settings, monkeypatch, django_capture_on_commit_callbacks):
    from training import dispatch

    monkeypatch.setattr(dispatch, "send", lambda name, pk: "t")
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 1
    first, second = create(alice, name="a"), create(alice, name="b")
    with django_capture_on_commit_callbacks(execute=True):
        job = services.training_start(model=first, user=alice)
    assert TrainingJob.objects.get(pk=job.pk).task_id == "t"
    with pytest.raises(ServiceError, match="busy"):
        services.training_start(model=first, user=alice)
    with pytest.raises(ServiceError, match="1 jobs queued or running"):
        services.training_start(model=second, user=alice)


def test_stopping_a_queued_job_cancels_it(alice, monkeypatch, django_capture_on_commit_callbacks):
    from training import dispatch

    monkeypatch.setattr(dispatch, "send", lambda name, pk: "t")
    model = create(alice)
    job = services.training_start(model=model, user=alice)
    job = services.job_stop(job=job, user=alice)
    assert job.status == JobStatus.CANCELED and job.stop_requested
    with pytest.raises(ServiceError, match="already finished"):
        services.job_stop(job=job, user=alice)


def test_stopping_a_running_job_is_cooperative(alice):
    model = create(alice)
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)
    job = services.job_stop(job=job, user=alice)
    assert job.status == JobStatus.STOPPING and job.stop_requested
    model.refresh_from_db()
    assert model.status == RacingModel.Status.STOPPING


def test_orphaned_jobs_are_noticed(alice):
    model = create(alice)
    model.has_checkpoint = True
    model.save()
    old = timezone.now() - timezone.timedelta(minutes=30)
    # A job whose worker died is queued again (it resumes from its last checkpoint)...
    dead = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS,
                                      heartbeat_at=old, attempts=1, worker="w1@host#1")  # fmt: skip
    # ... until it has been claimed RACECRAFT_JOB_MAX_ATTEMPTS times: then it fails.
    gave_up = TrainingJob.objects.create(model=model, max_minutes=5, attempts=3,
                                         status=JobStatus.IN_PROGRESS,
                                         heartbeat_at=old)  # fmt: skip
    alive = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS,
                                       heartbeat_at=timezone.now())  # fmt: skip
    assert services.jobs_reap_orphans(stale_after_s=300) == 2
    for job in (dead, gave_up, alive):
        job.refresh_from_db()
    assert dead.status == JobStatus.QUEUED and dead.worker == ""
    assert gave_up.status == JobStatus.FAILED and "stopped unexpectedly 3 times" in gave_up.error
    assert alive.status == JobStatus.IN_PROGRESS


def test_a_restarted_worker_queues_its_old_jobs_again(alice):
    model = create(alice)
    running = {"track_id": "racecraft_oval", "status": JobStatus.IN_PROGRESS, "attempts": 1}
    job = EvaluationJob.objects.create(model=model, worker="w1@host#123", **running)
    other = EvaluationJob.objects.create(model=model, worker="w2@host#123", **running)
    assert services.jobs_requeue_for_worker(worker="w1@host") == 1
    job.refresh_from_db()
    other.refresh_from_db()
    assert job.status == JobStatus.QUEUED and other.status == JobStatus.IN_PROGRESS


def test_evaluation_needs_a_checkpoint_and_valid_laps(alice):
    model = create(alice)
    with pytest.raises(ServiceError, match="train this model"):
        services.evaluation_start(model=model, user=alice)
    with pytest.raises(ServiceError, match="3 to 5 laps"):
        services.evaluation_start(model=model, user=alice, laps=7)


def test_clone_keeps_the_number_of_actions(alice):
    model = create(alice)
    model.has_checkpoint = True
    model.save()
    with pytest.raises(ServiceError, match="keeps the number of actions"):
        services.model_clone(model=model, owner=alice, name="c", action_space=ACTIONS[:2])


def test_delete_refused_while_training(alice):
    model = create(alice)
    TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)
    with pytest.raises(ServiceError, match="stop the model's training"):
        services.model_delete(model=model, user=alice)


@pytest.mark.django_db(transaction=True)
def test_a_heartbeat_thread_stamps_a_running_job(alice):
    """The stamp comes from a thread of its own, so a long policy update cannot starve it."""
    import time

    from training.worker.common import Heartbeat

    model = create(alice)
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)
    with Heartbeat(TrainingJob, job.pk, every=0.05):
        time.sleep(0.5)  # the main thread is busy; beats go on
    job.refresh_from_db()
    assert job.heartbeat_at is not None
    assert (timezone.now() - job.heartbeat_at).total_seconds() < 2
    assert services.jobs_reap_orphans(stale_after_s=300) == 0


def test_a_deepracer_car_archive_imports_as_a_model_that_drives_the_same(alice, ppo_discrete):
    from racing.env import RacingEnv
    from training.interchange.export import build_car_archive
    from training.rl.checkpoints import load_checkpoint
    from training.store import get_store, keys_for

    archive = build_car_archive(ppo_discrete.metadata, ppo_discrete.model)
    model = services.model_import(owner=alice, name="from-the-car", upload=archive)
    assert model.imported and model.has_checkpoint
    assert "Imported from DeepRacer's agent/model.pb" in model.description
    assert "value function fresh" in model.description  # the car archive holds only the policy
    assert model.reward_function.strip()  # an example reward to start from
    imported = load_checkpoint(get_store().get_bytes(keys_for(model.pk).best),
                               services.model_metadata(model))  # fmt: skip
    env = RacingEnv("racecraft_summit")
    obs, _ = env.reset(seed=4)
    for _ in range(10):
        ours, _ = imported.predict(obs, deterministic=True)
        theirs, _ = ppo_discrete.model.predict(obs, deterministic=True)
        assert int(ours) == int(theirs)
        obs, *_ = env.step(int(theirs))
    env.close()


def test_an_archive_that_is_neither_kind_is_refused_clearly(alice):
    import io
    import tarfile

    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        info = tarfile.TarInfo("notes.txt")
        info.size = 5
        tar.addfile(info, io.BytesIO(b"hello"))
    with pytest.raises(ServiceError) as refused:
        services.model_import(owner=alice, name="junk", upload=buffer.getvalue())
    assert refused.value.field == "archive" and refused.value.message
    assert not RacingModel.objects.filter(name="junk").exists()


def test_a_reward_that_fails_only_in_training_fails_the_job_once_with_its_line(alice):
    from training.sandbox import RewardError, RewardFunctionError, SandboxError
    from training.worker.common import fail_with

    job = TrainingJob.objects.create(model=create(alice), max_minutes=5,
                                     status=JobStatus.IN_PROGRESS)  # fmt: skip
    error = RewardError("TEST_FAILURE", "ZeroDivisionError: division by zero", line=3)
    assert fail_with(job, RewardFunctionError(error), what="training",
                     clear=(SandboxError,)) == "failed"  # fmt: skip
    job.refresh_from_db()
    assert job.status == JobStatus.FAILED
    assert job.error == (
        "the reward function failed during training (line 3): ZeroDivisionError: division by zero"
    )
    # A second report of the same failure changes nothing: the job has its one final state.
    assert not services.job_fail(job=job, error="again")
    job.refresh_from_db()
    assert job.error.endswith("division by zero")


@pytest.mark.parametrize(
    ("error", "expected"),
    [
        (
            StoreUnavailable(
                "cannot write 'racecraft/alice-model/model/last.zip' at MinioStore("
                "endpoint='10.1.2.3:9000', bucket='deepracer-secret-bucket'): connection refused",
                action="write",
                key="racecraft/alice-model/model/last.zip",
            ),
            "training failed: the model store is unavailable right now; try again in a minute",
        ),
        (
            StoreError(
                "cannot write '/srv/racecraft/var/store/7/model/last.zip': No space left on device",
                action="write",
                key="7/model/last.zip",
                reason="No space left on device",
            ),
            "training failed: the model store could not write last.zip: No space left on device",
        ),
    ],
)
def test_a_store_failure_fails_the_job_without_endpoint_bucket_or_folder(alice, error, expected):
    from training.worker.common import fail_with

    job = TrainingJob.objects.create(model=create(alice), max_minutes=5,
                                     status=JobStatus.IN_PROGRESS)  # fmt: skip
    assert fail_with(job, error, what="training", clear=(StoreError,)) == "failed"
    job.refresh_from_db()
    assert job.error == expected
    for secret in ("10.1.2.3", "9000", "deepracer-secret-bucket", "/srv", "alice-model", "/7/"):
        assert secret not in job.error
