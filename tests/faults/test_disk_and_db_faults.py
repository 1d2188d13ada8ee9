"""A full disk while a checkpoint is written, and a database connection dropped mid-request and
mid-job: a clear failure (or a retry that works), the old checkpoint intact, never a 500, never
a job stuck."""

from __future__ import annotations

import contextlib
import resource
import signal
import subprocess
import uuid
from pathlib import Path

import pytest
from django.contrib.auth import get_user_model
from django.db import connection
from django.utils import timezone

from training import services
from training.models import JobStatus, RacingModel, TrainingJob
from training.rl.runner import EvaluationOutcome, IterationResult
from training.storage import LocalStore, StoreError
from training.store import get_store, keys_for
from training.worker.common import fail_with
from training.worker.training import CLEAR_ERRORS, JobHooks

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"
OLD = b"the old checkpoint" * 10


@contextlib.contextmanager
def small_disk(folder: Path, limit: int = 64 * 1024):
    """A disk that fills at ``limit`` bytes: a tiny tmpfs when this process may mount one (it
    answers ENOSPC, like a full disk), else a file-size limit (EFBIG) on this process."""
    folder.mkdir(parents=True, exist_ok=True)
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={limit}", "tmpfs", str(folder)],
                             capture_output=True).returncode == 0  # fmt: skip
    if mounted:
        try:
            yield "ENOSPC"
        finally:
            subprocess.run(["umount", "-l", str(folder)], check=False)
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        yield "EFBIG"
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)


def test_a_full_disk_fails_a_store_write_clearly_and_keeps_the_old_object(tmp_path):
    root = tmp_path / "disk"
    with small_disk(root) as how:
        store = LocalStore(root)
        store.put_bytes("1/model/last.zip", OLD)
        with pytest.raises(StoreError) as failure:
            store.put_bytes("1/model/last.zip", b"\x01" * (256 * 1024))
        message = str(failure.value)
        assert "No space left" in message or "too large" in message, (how, message)
        assert store.get_bytes("1/model/last.zip") == OLD
        assert list((root / ".racecraft-tmp").iterdir()) == []  # no half-written file left


@pytest.mark.django_db
def test_a_full_disk_while_writing_a_checkpoint_fails_the_job_clearly(tmp_path, settings):
    settings.STORE_DIR = tmp_path / "disk"
    with small_disk(tmp_path / "disk") as how:
        if how == "EFBIG" and connection.vendor == "sqlite":
            pytest.skip("a file-size limit would also stop SQLite's own writes")
        owner = get_user_model().objects.create_user("alice", password="pw-alice-123")
        model = services.model_create(owner=owner, name="full", track_id="racecraft_oval",
                                      action_space=ACTIONS, reward_function=REWARD,
                                      validate_reward=False)  # fmt: skip
        keys = keys_for(model.pk)
        get_store().put_bytes(keys.last, OLD)
        get_store().put_bytes(keys.best, OLD)
        RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
        job = TrainingJob.objects.create(model=model, max_minutes=5, worker="w#1",
                                         status=JobStatus.IN_PROGRESS)  # fmt: skip
        job = TrainingJob.objects.select_related("model").get(pk=job.pk)
        hooks = JobHooks(job)
        result = IterationResult(
            iteration=1, episodes=1, steps=10, total_steps=10, train_reward=0.0,
            train_progress=0.0, evaluation=EvaluationOutcome([50.0], ["off_track"], [[]], [0.0]),
            elapsed_s=1.0, rollout_s=0.5, update_s=0.3, eval_s=0.2, best=True,
        )  # fmt: skip
        try:
            with pytest.raises(StoreError) as failure:
                hooks.on_iteration(result, b"\x02" * (256 * 1024), [])
            assert fail_with(job, failure.value, what="training", clear=CLEAR_ERRORS) == "failed"
        finally:
            hooks.close()
        job.refresh_from_db()
        assert job.status == JobStatus.FAILED
        assert "last.zip" in job.error
        assert "No space left" in job.error or "too large" in job.error
        assert get_store().get_bytes(keys.last) == OLD and get_store().get_bytes(keys.best) == OLD
        model.refresh_from_db()
        assert model.status == RacingModel.Status.READY  # the old checkpoint is still usable


# ------------------------------------------------------------------------------ the database
needs_postgres = pytest.mark.skipif(
    connection.vendor != "postgresql", reason="drops connections with pg_terminate_backend"
)


@needs_postgres
@pytest.mark.django_db(transaction=True)
def test_a_connection_dropped_mid_request_is_a_503_then_the_next_request_works(client):
    from django.db import connections

    owner = get_user_model().objects.create_user("alice", password="pw-alice-123")
    client.force_login(owner)
    assert client.get("/models/").status_code == 200
    with connections["default"].cursor() as cursor:
        cursor.execute("SELECT pg_backend_pid()")
        pid = cursor.fetchone()[0]
    other = connections.create_connection("default")
    try:
        with other.cursor() as cursor:  # another session kills this one's backend
            cursor.execute("SELECT pg_terminate_backend(%s)", [pid])
    finally:
        other.close()
    response = client.get("/models/")
    assert response.status_code == 503 and b"Database unavailable" in response.content
    connection.close_if_unusable_or_obsolete()  # what Django does at every request's end
    assert client.get("/models/").status_code == 200


@needs_postgres
@pytest.mark.django_db(transaction=True)
def test_worker_calls_reconnect_after_a_dropped_connection():
    owner = get_user_model().objects.create_user(f"u{uuid.uuid4().hex[:6]}", password="pw-x-12345")
    model = services.model_create(owner=owner, name="db", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False)  # fmt: skip
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS,
                                     worker="w#1")  # fmt: skip
    from django.db import connections

    with connections["default"].cursor() as cursor:
        cursor.execute("SELECT pg_backend_pid()")
        pid = cursor.fetchone()[0]
    other = connections.create_connection("default")
    with other.cursor() as cursor:
        cursor.execute("SELECT pg_terminate_backend(%s)", [pid])
    other.close()
    services.job_heartbeat(job_model=TrainingJob, job_id=job.pk)  # reconnects, does not raise
    assert not services.job_stop_requested(job=job)
    assert services.job_fail(job=job, error="clear message")
    job.refresh_from_db()
    assert job.status == JobStatus.FAILED and job.heartbeat_at <= timezone.now()
