"""Sign-up and log-in are throttled (django-ratelimit): past the rate, 429 before the view."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.core.cache import cache
from django.test import Client

pytestmark = pytest.mark.django_db
PASSWORD = "correct-horse-battery-9"


@pytest.fixture(autouse=True)
def _fresh_counts():
    cache.clear()
    yield
    cache.clear()


def test_log_in_attempts_are_limited_per_address(settings) -> None:
    settings.RACECRAFT_LOGIN_RATE = "3/m"
    get_user_model().objects.create_user("alice", password=PASSWORD)
    client = Client()
    codes = [
        client.post("/accounts/login/", {"username": f"guess{i}", "password": "x"}).status_code
        for i in range(4)
    ]
    assert codes[:3] == [200, 200, 200] and codes[3] == 429
    # Even the right password waits: the address is over its rate.
    response = client.post("/accounts/login/", {"username": "alice", "password": PASSWORD})
    assert response.status_code == 429 and "Too many attempts" in response.content.decode()


def test_log_in_attempts_are_limited_per_user_name(settings) -> None:
    settings.RACECRAFT_LOGIN_RATE = "2/m"
    codes = []
    for i in range(3):  # three addresses, one account
        client = Client(REMOTE_ADDR=f"10.0.0.{i + 1}")
        codes.append(client.post("/accounts/login/", {"username": "Alice", "password": "x"}))
    assert [r.status_code for r in codes] == [200, 200, 429]


def test_sign_ups_are_limited_per_address(settings) -> None:
    settings.RACECRAFT_SIGNUP_RATE = "2/h"
    client = Client()
    codes = []
    for i in range(3):
        data = {"username": f"dana{i}", "password1": PASSWORD, "password2": PASSWORD}
        codes.append(client.post("/accounts/signup/", data).status_code)
        client.logout()
    assert codes == [302, 302, 429]
    assert get_user_model().objects.count() == 2


def test_pages_and_other_posts_are_not_throttled(settings) -> None:
    settings.RACECRAFT_SIGNUP_RATE = "1/h"
    client = Client()
    for _ in range(3):
        assert client.get("/accounts/signup/").status_code == 200
