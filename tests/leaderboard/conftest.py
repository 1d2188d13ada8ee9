"""Fixtures of the league tests: the characters (see league_helpers)."""

from __future__ import annotations

import pytest
from league_helpers import make_event, make_user


@pytest.fixture
def alice(db):
    return make_user("alice", alias="Alice-R")


@pytest.fixture
def bob(db):
    return make_user("bob", alias="BobRacer")


@pytest.fixture
def charlie(db):
    return make_user("charlie", alias="Charlie")


@pytest.fixture
def fran(db):
    return make_user("fran", alias="Fran", facilitator=True)


@pytest.fixture
def event(fran):
    return make_event(fran)


@pytest.fixture(autouse=True)
def _fast_passwords(settings) -> None:
    settings.PASSWORD_HASHERS = ["django.contrib.auth.hashers.MD5PasswordHasher"]
