"""Sign-up and log-in are throttled (django-ratelimit): past the rate, 429 before the view.

The limiter's clock is frozen (tests/console/ratelimit_clock.py), so no window ends mid-test."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("fresh_rate_counts")]
PASSWORD = "correct-horse-battery-9"


def test_log_in_attempts_are_limited_per_address(settings, frozen_clock) -> None:
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
    assert response.status_code == 429
    assert "Too many log-in attempts from your address" in response.content.decode()
    frozen_clock.advance(60)  # the window has passed: the right password gets in
    response = client.post("/accounts/login/", {"username": "alice", "password": PASSWORD})
    assert response.status_code == 302 and client.session["_auth_user_id"]


def test_log_in_attempts_are_limited_per_user_name(settings, frozen_clock) -> None:
    settings.RACECRAFT_LOGIN_RATE = "2/m"
    codes = []
    for i in range(3):  # three addresses, one account
        client = Client(REMOTE_ADDR=f"10.0.0.{i + 1}")
        codes.append(client.post("/accounts/login/", {"username": "Alice", "password": "x"}))
    assert [r.status_code for r in codes] == [200, 200, 429]


def test_sign_ups_are_limited_per_address(settings, frozen_clock) -> None:
    settings.RACECRAFT_SIGNUP_RATE = "2/h"
    client = Client()
    codes = []
    for i in range(3):
        data = {"username": f"dana{i}", "password1": PASSWORD, "password2": PASSWORD}
        codes.append(client.post("/accounts/signup/", data).status_code)
        client.logout()
    assert codes == [302, 302, 429]
    assert get_user_model().objects.count() == 2
    refused = client.post("/accounts/signup/", {"username": "erin", "password1": PASSWORD,
                                                "password2": PASSWORD})  # fmt: skip
    assert "Too many attempts from your address" in refused.content.decode()


def test_pages_and_other_posts_are_not_throttled(settings, frozen_clock) -> None:
    settings.RACECRAFT_SIGNUP_RATE = "1/h"
    client = Client()
    for _ in range(3):
        assert client.get("/accounts/signup/").status_code == 200


def test_counts_are_shared_between_processes(settings, child_env, tmp_path) -> None:
    """The counts live in Redis (CACHES): attempts on this process and on a separate web
    server (daphne) count against one limit, so N web processes do not allow N times the
    rate. A ten-year window, so the count cannot roll over between the two processes."""
    import urllib.error
    import urllib.request

    from tests.support import daphne_process

    settings.RACECRAFT_LOGIN_RATE = "3/3650d"
    env = {**child_env, "RACECRAFT_LOGIN_RATE": "3/3650d"}
    with daphne_process(env=env, log_path=tmp_path / "daphne.log") as web:

        def post_there() -> int:
            request = urllib.request.Request(
                f"{web.url}/accounts/login/", data=b"username=x&password=y", method="POST"
            )
            try:
                return urllib.request.urlopen(request, timeout=30).status
            except urllib.error.HTTPError as exc:
                return exc.code

        assert post_there() == 403  # counted there (then refused: no CSRF token)
        here = [
            Client().post("/accounts/login/", {"username": f"u{i}", "password": "x"}).status_code
            for i in range(3)
        ]
        assert here == [200, 200, 429]  # the server's attempt counted here
        assert post_there() == 429  # and this process's there
