"""Fixtures of the league tests: tests/conftest.py's characters with their racer aliases, and
Fran the facilitator (see league_helpers)."""

from __future__ import annotations

import pytest
from league_helpers import make_event, make_user, with_alias


@pytest.fixture
def alice(alice):
    return with_alias(alice, "Alice-R")


@pytest.fixture
def bob(bob):
    return with_alias(bob, "BobRacer")


@pytest.fixture
def charlie(charlie):
    return with_alias(charlie, "Charlie")


@pytest.fixture
def fran(db):
    return make_user("fran", alias="Fran", facilitator=True)


@pytest.fixture
def event(fran):
    return make_event(fran)


@pytest.fixture(autouse=True)
def _fast_passwords(settings) -> None:
    settings.PASSWORD_HASHERS = ["django.contrib.auth.hashers.MD5PasswordHasher"]
