"""The object store goes away: calls are retried with backoff for transient errors, a write
outlives a 30 s outage of a real S3 server (moto on loopback), and model creation, cloning and
import leave nothing half-made and say "storage unavailable, try again" (a 503 for pages and
downloads, never a 500)."""

from __future__ import annotations

import io
import os
import socket
import tarfile
import threading
import time

import pytest
from moto.server import ThreadedMotoServer

from training import services
from training.models import RacingModel
from training.services import ServiceError, downloads
from training.storage import (
    LocalStore,
    MinioStore,
    ObjectNotFound,
    RetryingStore,
    StoreError,
    StoreUnavailable,
)
from training.store import get_store, keys_for

ACCESS, SECRET = "testing-access", "testing-secret"  # noqa: S105 - moto's fake credentials
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"


class Flaky(LocalStore):
    """A local store whose first ``failures`` calls fail as an unreachable server would."""

    def __init__(self, root, failures: int, error: type[StoreError] = StoreUnavailable) -> None:
        super().__init__(root)
        self.failures, self.error, self.calls = failures, error, 0

    def put_bytes(self, key, data, content_type="application/octet-stream") -> None:
        self.calls += 1
        if self.calls <= self.failures:
            raise self.error("server unreachable")
        super().put_bytes(key, data, content_type)


class FakeClock:
    def __init__(self) -> None:
        self.now, self.slept = 0.0, []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


def test_transient_errors_are_retried_with_backoff(tmp_path):
    clock = FakeClock()
    inner = Flaky(tmp_path, failures=5)
    store = RetryingStore(inner, retry_s=60, sleep=clock.sleep, clock=clock)
    store.put_bytes("a/b", b"1")
    assert inner.calls == 6 and store.get_bytes("a/b") == b"1"
    assert clock.slept == [0.2, 0.4, 0.8, 1.6, 3.2]  # doubling, capped at 5 s


def test_retries_give_up_after_their_window(tmp_path):
    clock = FakeClock()
    inner = Flaky(tmp_path, failures=10**6)
    store = RetryingStore(inner, retry_s=30, sleep=clock.sleep, clock=clock)
    with pytest.raises(StoreUnavailable):
        store.put_bytes("a", b"1")
    assert clock.now == pytest.approx(30.0)


def test_lasting_errors_are_not_retried(tmp_path):
    clock = FakeClock()
    inner = Flaky(tmp_path, failures=1, error=StoreError)  # e.g. a full disk
    store = RetryingStore(inner, retry_s=60, sleep=clock.sleep, clock=clock)
    with pytest.raises(StoreError):
        store.put_bytes("a", b"1")
    with pytest.raises(ObjectNotFound):
        store.get_bytes("missing")
    assert clock.slept == []


def test_an_unreachable_minio_is_transient():
    store = MinioStore("127.0.0.1:9", ACCESS, SECRET, bucket="deepracer-x", timeout=1, retries=0)
    with pytest.raises(StoreUnavailable):
        store.get_bytes("a")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def moto_env():
    saved = {k: os.environ.get(k) for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY")}
    os.environ["AWS_ACCESS_KEY_ID"], os.environ["AWS_SECRET_ACCESS_KEY"] = ACCESS, SECRET
    yield
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


@pytest.mark.slow
def test_a_write_outlives_a_30_s_outage_of_the_store(moto_env):
    """A checkpoint write issued while the S3 server is down for 30 s completes once it is
    back (the worker's patience is longer than the outage), and the data is intact."""
    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    inner = MinioStore(f"127.0.0.1:{port}", ACCESS, SECRET, bucket="deepracer-outage",
                       timeout=2, retries=0)  # fmt: skip
    store = RetryingStore(inner, retry_s=120)
    store.put_bytes("m/last.zip", b"before")
    server.stop()
    with pytest.raises(StoreUnavailable):
        inner.put_bytes("m/last.zip", b"x")  # really down
    restarted = threading.Event()

    def come_back() -> None:
        time.sleep(30)
        again = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
        again.start()
        restarted.again = again  # type: ignore[attr-defined]
        restarted.set()

    thread = threading.Thread(target=come_back, daemon=True)
    started = time.monotonic()
    thread.start()
    payload = os.urandom(200_000)
    try:
        store.put_bytes("m/last.zip", payload)
        assert time.monotonic() - started >= 29
        assert store.get_bytes("m/last.zip") == payload
    finally:
        thread.join(60)
        if restarted.is_set():
            restarted.again.stop()  # type: ignore[attr-defined]


# ------------------------------------------------------------------------------ services
class DownStore(LocalStore):
    """Reads work, writes fail as an unreachable server would."""

    def put_bytes(self, key, data, content_type="application/octet-stream") -> None:
        raise StoreUnavailable("cannot write: connection refused")


@pytest.fixture
def down_store(monkeypatch, tmp_path, settings):
    settings.STORE_DIR = tmp_path / "store"
    store = DownStore(tmp_path / "store")
    for module in ("models", "downloads", "background"):
        monkeypatch.setattr(f"training.services.{module}.get_store", lambda: store)
    return store


def _create(owner, name="m1"):
    return services.model_create(owner=owner, name=name, track_id="racecraft_oval",
                                 action_space=ACTIONS, reward_function=REWARD,
                                 validate_reward=False)  # fmt: skip


@pytest.mark.django_db
def test_create_with_the_store_down_leaves_nothing_and_says_try_again(alice, down_store):
    with pytest.raises(ServiceError, match="store is unavailable.*try again"):
        _create(alice)
    assert not RacingModel.objects.exists()
    assert down_store.list() == []


def _real_checkpoint() -> bytes:
    from stable_baselines3 import PPO

    from racing.env import RacingEnv
    from training.rl.policies import policy_kwargs

    env = RacingEnv("racecraft_oval", action_space=ACTIONS)
    model = PPO("CnnPolicy", env, policy_kwargs=policy_kwargs(), n_steps=64, batch_size=32,
                device="cpu", seed=1)  # fmt: skip
    buffer = io.BytesIO()
    model.save(buffer)
    env.close()
    return buffer.getvalue()


@pytest.mark.django_db
def test_clone_and_import_with_the_store_down_leave_nothing(alice, settings, tmp_path,
                                                            monkeypatch):  # fmt: skip
    settings.STORE_DIR = tmp_path / "store"
    parent = _create(alice, "parent")
    checkpoint = _real_checkpoint()
    get_store().put_bytes(keys_for(parent.pk).best, checkpoint)
    get_store().put_bytes(keys_for(parent.pk).last, checkpoint)
    RacingModel.objects.filter(pk=parent.pk).update(has_checkpoint=True)
    parent.refresh_from_db()
    archive = downloads.virtual_model_archive(parent)
    down = DownStore(tmp_path / "store")
    monkeypatch.setattr("training.services.models.get_store", lambda: down)
    with pytest.raises(ServiceError, match="unavailable"):
        services.model_clone(model=parent, owner=alice, name="clone")
    with pytest.raises(ServiceError, match="unavailable"):
        services.model_import(owner=alice, name="imported", upload=io.BytesIO(archive))
    assert list(RacingModel.objects.values_list("name", flat=True)) == ["parent"]
    assert all(k.startswith(keys_for(parent.pk).prefix) for k in down.list())  # only the parent
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:  # the archive itself was fine
        assert tar.getnames()


@pytest.mark.django_db
def test_pages_and_downloads_answer_503_when_the_store_is_down(client, alice, down_store,
                                                               monkeypatch):  # fmt: skip
    model = RacingModel.objects.create(
        owner=alice, name="m1", track_id="racecraft_oval", neural_network="RACECRAFT_LEAN_CNN",
        action_space_type="discrete", action_space=ACTIONS, algorithm="clipped_ppo",
        reward_function=REWARD, has_checkpoint=True,
    )  # fmt: skip

    def unreachable(self, key):
        raise StoreUnavailable("cannot read: connection refused")

    monkeypatch.setattr(DownStore, "get_bytes", unreachable)
    client.force_login(alice)
    response = client.get(f"/models/{model.pk}/download/car/")
    assert response.status_code == 503, response.status_code
    assert b"unavailable" in response.content and response["Retry-After"]
