"""Fault injection through real components (issue #15): a Celery worker's process is killed
mid-training, Redis is restarted mid-training with a job queued, the object store (moto's S3
server on loopback) stops for 30 s mid-training. Each time the job ends well or clearly, loses
at most the iteration in flight, and nothing is left stuck. Every wait is on a condition with a
generous deadline."""

from __future__ import annotations

import os
import signal
import tempfile
import time
from pathlib import Path

import pytest
import redis
from channels.layers import channel_layers
from django.conf import settings as django_settings
from django.contrib.auth import get_user_model
from django.db import connection
from kombu import pools as kombu_pools
from moto.server import ThreadedMotoServer

from console.celery import app as celery_app
from console.launcher import EmbeddedRedis, Supervisor
from console.redisconf import celery_settings
from console.redisconf import channel_layers as channel_layers_setting
from tests.faults.workers import SMALL, celery_worker, wait_for
from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from training import services
from training.models import IterationMetric, JobStatus, RacingModel, TrainingJob
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow, pytest.mark.timeout(2400)]
TRAIN_DEADLINE_S = 600


@pytest.fixture
def store_dir(tmp_path, settings):
    settings.STORE_DIR = tmp_path / "store"
    return settings.STORE_DIR


def _model(owner, name: str, minutes: int = 3) -> RacingModel:
    return services.model_create(owner=owner, name=name, track_id="racecraft_oval",
                                 action_space=ACTIONS, reward_function=REWARD,
                                 hyperparameters=SMALL, max_minutes=minutes, seed=1)  # fmt: skip


def _job(pk: int) -> TrainingJob:
    return TrainingJob.objects.get(pk=pk)


def _finish(job_id: int, owner, log_path: Path) -> TrainingJob:
    """Stop the job (it has shown what the test needed) and wait for its final state."""
    job = _job(job_id)
    if job.is_active:
        try:
            services.job_stop(job=job, user=owner)
        except services.ServiceError:
            pass
    return wait_for(lambda: (j := _job(job_id)).status in ("COMPLETED", "FAILED", "CANCELED")
                    and j, TRAIN_DEADLINE_S, "the job's final state", log_path)  # fmt: skip


def test_sigkill_of_the_worker_process_mid_training_resumes_the_job(store_dir, redis_env):
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    log_path = store_dir.parent / "worker.log"
    env = {**redis_env, "STORE_DIR": str(store_dir),
           "RACECRAFT_TRACKS_DIR": str(django_settings.RACECRAFT_TRACKS_DIR)}  # fmt: skip
    with celery_worker(log_path, env):
        model = _model(alice, "killed")
        job = services.training_start(model=model, user=alice)
        first = wait_for(lambda: (j := _job(job.pk)).iterations >= 1 and j, TRAIN_DEADLINE_S,
                         "a first iteration", log_path)  # fmt: skip
        pid = int(first.worker.rpartition("#")[2])
        os.kill(pid, signal.SIGKILL)  # the pool process running the job, mid-iteration
        done_before = _job(job.pk).iterations
        resumed = wait_for(
            lambda: (j := _job(job.pk)).attempts >= 2 and j.iterations > done_before and j,
            TRAIN_DEADLINE_S, "the job to resume and finish another iteration", log_path,
        )  # fmt: skip
        assert not resumed.worker.endswith(f"#{pid}")
        assert "its own last checkpoint" in resumed.resumed_from, resumed.resumed_from
        final = _finish(job.pk, alice, log_path)
    assert final.status == JobStatus.COMPLETED, final.error
    numbers = list(IterationMetric.objects.filter(job_id=job.pk)
                   .order_by("iteration").values_list("iteration", flat=True))  # fmt: skip
    assert numbers == list(range(1, len(numbers) + 1))  # nothing recorded twice or skipped
    assert numbers[-1] >= done_before + 1  # at most the iteration in flight was lost
    assert get_store().exists(keys_for(model.pk).last)
    model.refresh_from_db()
    assert model.status == RacingModel.Status.READY


def _reset_broker_pools() -> None:
    """Forget connections to the previous broker (the next send connects to the new URL).

    kombu keeps one pool per broker URL in a registry of its own: closing a pool without
    clearing that registry would hand the closed pool back once the URL is used again (the
    next tests' "Acquire on closed pool")."""
    kombu_pools.reset()
    celery_app._pool = None
    celery_app.amqp._producer_pool = None
    # The result backend is cached too (per thread, or once when thread-safe).
    celery_app._local.__dict__.pop("backend", None)
    celery_app._backend_cache = None


@pytest.fixture
def own_redis():
    """A Redis of this test's own (persistent, on a unix socket), that it may restart; the
    test process's settings, Celery app and channel layer point at it meanwhile."""
    folder = tempfile.mkdtemp(prefix="rc-faults-redis-")
    embedded = EmbeddedRedis(Path(folder) / "redis.sock")
    sup = Supervisor(stop_timeout=5)
    child = {"c": sup.start(embedded.spec())}
    sup.wait_until(embedded.ping, what="own Redis", timeout=30)
    url = embedded.url
    celery = celery_settings(url, "")
    names = ("REDIS_URL", "REDIS_PREFIX", "CHANNEL_LAYERS")
    saved = {n: getattr(django_settings, n) for n in names}
    saved_conf = {k: celery_app.conf[k] for k in ("broker_url", "result_backend",
                  "broker_transport_options", "result_backend_transport_options")}  # fmt: skip
    django_settings.REDIS_URL, django_settings.REDIS_PREFIX = url, ""
    django_settings.CHANNEL_LAYERS = channel_layers_setting(url, "")
    celery_app.conf.update(
        broker_url=celery["CELERY_BROKER_URL"],
        result_backend=celery["CELERY_RESULT_BACKEND"],
        broker_transport_options={},
        result_backend_transport_options={},
    )
    _reset_broker_pools()
    channel_layers.backends.clear()

    def restart() -> None:
        old = child["c"]
        os.kill(old.process.pid, signal.SIGKILL)  # a crash
        old.process.wait()
        sup.children.remove(old)
        time.sleep(2)  # down for a moment: clients see refused connections
        child["c"] = sup.start(embedded.spec())
        sup.wait_until(embedded.ping, what="restarted Redis", timeout=30)

    try:
        yield url, restart
    finally:
        for n, v in saved.items():
            setattr(django_settings, n, v)
        celery_app.conf.update(**saved_conf)
        _reset_broker_pools()
        channel_layers.backends.clear()
        sup.stop_all()


def test_redis_restarted_mid_training_with_a_job_queued(store_dir, own_redis):
    url, restart = own_redis
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    log_path = store_dir.parent / "worker.log"
    env = {"REDIS_URL": url, "REDIS_PREFIX": "", "STORE_DIR": str(store_dir),
           "RACECRAFT_TRACKS_DIR": str(django_settings.RACECRAFT_TRACKS_DIR)}  # fmt: skip
    with celery_worker(log_path, env):
        running = services.training_start(model=_model(alice, "running"), user=alice)
        wait_for(lambda: _job(running.pk).iterations >= 1, TRAIN_DEADLINE_S,
                 "a first iteration", log_path)  # fmt: skip
        queued = services.training_start(model=_model(alice, "queued", minutes=1), user=alice)
        wait_for(lambda: _job(queued.pk).task_id, 30, "the second job's task")
        assert _job(queued.pk).status == JobStatus.QUEUED  # the one worker process is busy
        restart()
        before = _job(running.pk).iterations
        wait_for(lambda: _job(running.pk).iterations > before, TRAIN_DEADLINE_S,
                 "an iteration after the restart", log_path)  # fmt: skip
        first = _finish(running.pk, alice, log_path)
        # The queued job's task survived the restart (the embedded Redis keeps an AOF).
        second = wait_for(lambda: (j := _job(queued.pk)).status != JobStatus.QUEUED and j,
                          TRAIN_DEADLINE_S, "the queued job to start", log_path)  # fmt: skip
        second = _finish(second.pk, alice, log_path)
    assert first.status == JobStatus.COMPLETED, first.error
    assert second.status == JobStatus.COMPLETED, second.error
    assert not TrainingJob.objects.filter(status__in=("QUEUED", "IN_PROGRESS")).exists()


def test_the_store_down_for_30_s_mid_training_does_not_fail_the_job(store_dir, redis_env,
                                                                     settings):  # fmt: skip
    """The models live in moto's S3 server; it stops for 30 s while the job trains; the
    worker's checkpoint writes wait it out and the job completes."""
    access, secret = "testing-access", "testing-secret"  # noqa: S105 - moto's fake credentials
    os.environ.setdefault("AWS_ACCESS_KEY_ID", access)
    os.environ.setdefault("AWS_SECRET_ACCESS_KEY", secret)
    from tests.support import free_port

    port = free_port()
    server = {"s": ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)}
    server["s"].start()
    minio = {"MINIO_ENDPOINT": f"127.0.0.1:{port}", "MINIO_ACCESS_KEY": access,
             "MINIO_SECRET_KEY": secret, "MINIO_BUCKET": "deepracer-outage"}  # fmt: skip
    for name, value in minio.items():
        setattr(settings, name, value)
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    log_path = store_dir.parent / "worker.log"
    env = {**redis_env, **minio, "RACECRAFT_STORE_WORKER_RETRY_S": "180",
           "RACECRAFT_TRACKS_DIR": str(django_settings.RACECRAFT_TRACKS_DIR)}  # fmt: skip
    try:
        with celery_worker(log_path, env):
            model = _model(alice, "outage")
            job = services.training_start(model=model, user=alice)
            wait_for(lambda: _job(job.pk).iterations >= 1, TRAIN_DEADLINE_S,
                     "a first iteration", log_path)  # fmt: skip
            server["s"].stop()
            down = _job(job.pk).iterations
            # While the store is down no iteration can finish (its checkpoint comes first),
            # and the worker says it is waiting, not failing.
            wait_for(lambda: "store unavailable" in log_path.read_text(), 240,
                     "a checkpoint write to wait for the store", log_path)  # fmt: skip
            time.sleep(30)
            assert _job(job.pk).status == JobStatus.IN_PROGRESS
            server["s"] = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
            server["s"].start()
            wait_for(lambda: _job(job.pk).iterations > down, TRAIN_DEADLINE_S,
                     "an iteration after the outage", log_path)  # fmt: skip
            final = _finish(job.pk, alice, log_path)
        assert final.status == JobStatus.COMPLETED, final.error
        assert get_store().exists(keys_for(model.pk).last)
    finally:
        server["s"].stop()


def test_a_queued_job_whose_task_redis_lost_is_sent_again_and_runs(store_dir, own_redis):
    """Redis restarted without its data while a job waited (no worker yet): the reaper sees
    the job's task is gone, sends it again, and a worker then runs the job."""
    url, _ = own_redis
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    log_path = store_dir.parent / "worker.log"
    job = services.training_start(model=_model(alice, "lost", minutes=1), user=alice)
    wait_for(lambda: _job(job.pk).task_id, 30, "the job's task")
    client = redis.Redis.from_url(url)
    client.flushall()  # a restart that kept nothing
    client.close()
    assert services.jobs_reap_orphans(lost_task_grace_s=0) == 1
    env = {"REDIS_URL": url, "REDIS_PREFIX": "", "STORE_DIR": str(store_dir),
           "RACECRAFT_TRACKS_DIR": str(django_settings.RACECRAFT_TRACKS_DIR)}  # fmt: skip
    with celery_worker(log_path, env):
        started = wait_for(lambda: (j := _job(job.pk)).status != JobStatus.QUEUED and j,
                           TRAIN_DEADLINE_S, "the job to start", log_path)  # fmt: skip
        assert started.status in (JobStatus.INITIALIZING, JobStatus.IN_PROGRESS)
        final = _finish(job.pk, alice, log_path)
    assert final.status == JobStatus.COMPLETED, final.error


needs_postgres = pytest.mark.skipif(
    connection.vendor != "postgresql", reason="drops connections with pg_terminate_backend"
)


WORKER_APP_NAME = "racecraft-fault-worker"


@needs_postgres
def test_database_connections_dropped_mid_training(store_dir, redis_env):
    """Every database session of the worker is killed (a database restart) mid-training:
    the worker reconnects and the job goes on, or fails with a clear message - never stuck."""
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    log_path = store_dir.parent / "worker.log"
    # The worker's sessions carry a name (libpq's PGAPPNAME), so that only they are killed:
    # the test process's other sessions (its threads') serve the tests that follow.
    env = {**redis_env, "STORE_DIR": str(store_dir), "PGAPPNAME": WORKER_APP_NAME,
           "RACECRAFT_TRACKS_DIR": str(django_settings.RACECRAFT_TRACKS_DIR)}  # fmt: skip
    with celery_worker(log_path, env):
        job = services.training_start(model=_model(alice, "dbdrop"), user=alice)
        wait_for(lambda: _job(job.pk).iterations >= 1, TRAIN_DEADLINE_S,
                 "a first iteration", log_path)  # fmt: skip
        with connection.cursor() as cursor:
            cursor.execute(
                "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity "
                "WHERE datname = current_database() AND application_name = %s",
                [WORKER_APP_NAME],
            )
            assert cursor.fetchone()[0] >= 1
        before = _job(job.pk).iterations
        wait_for(lambda: (j := _job(job.pk)).iterations > before or not j.is_active,
                 TRAIN_DEADLINE_S, "an iteration after the drop, or an end", log_path)  # fmt: skip
        final = _finish(job.pk, alice, log_path)
    assert final.status in (JobStatus.COMPLETED, JobStatus.FAILED)
    if final.status == JobStatus.FAILED:
        assert "OperationalError" in final.error or "connection" in final.error, final.error
    model = RacingModel.objects.get(pk=job.model_id)
    assert model.status == RacingModel.Status.READY  # its checkpoint is usable either way
