"""The admin's log-in page (/admin/login/) is throttled like the console's: per address and per
user name, 429 in words, and the right password waits too until the window has passed (the
limiter's clock is frozen, tests/console/ratelimit_clock.py, and moved on by the test)."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

from tests.console.ratelimit_clock import FrozenClock

pytestmark = pytest.mark.django_db
PASSWORD = "correct-horse-battery-9"
ADMIN_LOGIN = "/admin/login/"


@pytest.fixture
def admin_user():
    return get_user_model().objects.create_superuser("root", "root@example.com", PASSWORD)


def _log_in(client: Client, password: str, username: str = "root"):
    return client.post(ADMIN_LOGIN, {"username": username, "password": password,
                                     "next": "/admin/"})  # fmt: skip


def test_wrong_passwords_then_the_right_one_is_refused_until_the_window_passes(
    settings, admin_user, frozen_clock: FrozenClock
) -> None:
    settings.RACECRAFT_LOGIN_RATE = "5/m"
    client = Client()
    wrong = [_log_in(client, f"guess-{i}").status_code for i in range(5)]
    assert wrong == [200] * 5  # the admin's form again, "Please enter the correct ..."
    refused = _log_in(client, PASSWORD)
    assert refused.status_code == 429
    assert "Too many log-in attempts" in refused.content.decode()
    assert "_auth_user_id" not in client.session  # not logged in
    assert client.get("/admin/").status_code == 302  # still sent to the log-in page

    frozen_clock.advance(60)  # the window has passed
    response = _log_in(client, PASSWORD)
    assert response.status_code == 302 and response["Location"] == "/admin/"
    assert client.session["_auth_user_id"] == str(admin_user.pk)
    assert client.get("/admin/").status_code == 200


def test_one_user_name_is_protected_from_many_addresses(
    settings, admin_user, frozen_clock: FrozenClock
) -> None:
    settings.RACECRAFT_LOGIN_RATE = "3/m"
    codes = [
        _log_in(Client(REMOTE_ADDR=f"192.0.2.{i + 1}"), "guess", username="Root").status_code
        for i in range(3)
    ]
    assert codes == [200, 200, 200]
    fourth = _log_in(Client(REMOTE_ADDR="192.0.2.99"), PASSWORD)  # a fresh address, same name
    assert fourth.status_code == 429 and "for this user name" in fourth.content.decode()


def test_the_console_and_admin_log_in_pages_share_one_count(
    settings, admin_user, frozen_clock: FrozenClock
) -> None:
    """Guesses spread over both pages are not twice the rate."""
    settings.RACECRAFT_LOGIN_RATE = "4/m"
    client = Client()
    for i in range(2):
        assert client.post("/accounts/login/", {"username": f"u{i}", "password": "x"}).status_code \
            == 200  # fmt: skip
        assert _log_in(client, "x", username=f"v{i}").status_code == 200
    assert _log_in(client, PASSWORD).status_code == 429
    assert client.post("/accounts/login/", {"username": "root", "password": PASSWORD}) \
        .status_code == 429  # fmt: skip


def test_the_admin_log_in_page_itself_is_not_throttled(settings, frozen_clock) -> None:
    settings.RACECRAFT_LOGIN_RATE = "1/m"
    client = Client()
    assert [client.get(ADMIN_LOGIN).status_code for _ in range(3)] == [200, 200, 200]
