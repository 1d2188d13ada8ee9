"""Clients and models for the console's tests: Alice owns things, Charlie must never see them
(the characters themselves are tests/conftest.py's)."""

from __future__ import annotations

import pytest
from django.test import Client

from tests.conftest import clear_cache
from tests.console.ratelimit_clock import FrozenClock, freeze_ratelimit_clock
from training import services
from training.models import RacingModel

REWARD = "def reward_function(params):\n    return 1.0\n"
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]


@pytest.fixture
def alice_client(alice) -> Client:
    client = Client()
    client.force_login(alice)
    return client


@pytest.fixture
def charlie_client(charlie) -> Client:
    client = Client()
    client.force_login(charlie)
    return client


def make_model(owner, name: str = "alice-oval", **overrides) -> RacingModel:
    values = {
        "owner": owner,
        "name": name,
        "track_id": "racecraft_oval",
        "action_space": ACTIONS,
        "reward_function": REWARD,
        "validate_reward": False,
        "seed": 1,
        **overrides,
    }
    return services.model_create(**values)


@pytest.fixture
def alice_model(alice, store_dir) -> RacingModel:
    return make_model(alice)


@pytest.fixture
def fresh_rate_counts():
    """Rate-limit counts (Django's cache, in Redis) empty before and after the test."""
    clear_cache()
    yield
    clear_cache()


@pytest.fixture
def frozen_clock(monkeypatch: pytest.MonkeyPatch) -> FrozenClock:
    """django-ratelimit's clock, frozen: no window ends mid-test (ratelimit_clock.py)."""
    return freeze_ratelimit_clock(monkeypatch)
