"""Behind a reverse proxy, rate limits count per client, not per proxy: X-Forwarded-For is read
only from the proxies listed in RACECRAFT_TRUSTED_PROXIES, and only its right-most address that
is not one of them (what the proxy itself wrote). From anyone else the header changes nothing.

Through the real limiter (django-ratelimit counting in Redis), with its clock frozen
(tests/console/ratelimit_clock.py) so that no window ends mid-test, and through the web server
exactly as `manage.py up` starts it (console/launcher.py ``web_spec``)."""

from __future__ import annotations

import itertools
import socket
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from django.test import Client, RequestFactory

from console.launcher import ConsoleOptions, Supervisor, web_spec
from console.throttle import client_ip
from tests.support import free_port

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("fresh_rate_counts")]
PROXY = "10.0.0.1"
LOGIN = "/accounts/login/"
_NAMES = itertools.count()


def _attempt(peer: str, forwarded: str | None = None, username: str = "") -> int:
    """One wrong log-in from ``peer`` (the connecting address), a fresh user name each time
    unless given, so only the per-address count can refuse it."""
    headers = {"REMOTE_ADDR": peer}
    if forwarded is not None:
        headers["HTTP_X_FORWARDED_FOR"] = forwarded
    data = {"username": username or f"guess-{next(_NAMES)}", "password": "x"}
    return Client(**headers).post(LOGIN, data).status_code


def test_by_default_the_header_is_ignored(settings, frozen_clock) -> None:
    """No trusted proxy (the default): a client naming a new address in X-Forwarded-For each
    time still has one bucket, its connecting address."""
    settings.RACECRAFT_LOGIN_RATE = "3/m"
    codes = [_attempt("192.0.2.10", f"198.51.100.{i}") for i in range(4)]
    assert codes == [200, 200, 200, 429]
    assert _attempt("192.0.2.11") == 200  # another address, another bucket


def test_behind_a_trusted_proxy_each_client_has_its_own_bucket(settings, frozen_clock) -> None:
    settings.RACECRAFT_TRUSTED_PROXIES = [PROXY]
    settings.RACECRAFT_LOGIN_RATE = "3/m"
    assert [_attempt(PROXY, "203.0.113.5") for _ in range(4)] == [200, 200, 200, 429]
    # Another client through the same proxy is not blocked by the first one's attempts.
    assert _attempt(PROXY, "203.0.113.6") == 200
    # The first client cannot escape by prepending an address of its choice: the proxy appends
    # the real one, which is the right-most.
    assert _attempt(PROXY, "198.51.100.1, 203.0.113.5") == 429


def test_sign_ups_through_a_trusted_proxy_are_counted_per_client(settings, frozen_clock) -> None:
    """The issue's case: 5 sign-ups an hour from anyone used to block everyone's."""
    settings.RACECRAFT_TRUSTED_PROXIES = [PROXY]
    settings.RACECRAFT_SIGNUP_RATE = "1/h"
    password = "correct-horse-battery-9"

    def sign_up(client_address: str, name: str) -> int:
        client = Client(REMOTE_ADDR=PROXY, HTTP_X_FORWARDED_FOR=client_address)
        data = {"username": name, "password1": password, "password2": password}
        return client.post("/accounts/signup/", data).status_code

    assert sign_up("203.0.113.5", "dana") == 302
    assert sign_up("203.0.113.5", "dana2") == 429
    assert sign_up("203.0.113.6", "erin") == 302


def test_a_forged_header_from_an_untrusted_address_changes_nothing(settings, frozen_clock) -> None:
    settings.RACECRAFT_TRUSTED_PROXIES = [PROXY]
    settings.RACECRAFT_LOGIN_RATE = "2/m"
    # Not the proxy: the header is the client's own text, so all of these count for 192.0.2.50.
    codes = [_attempt("192.0.2.50", f"{PROXY}, 203.0.113.{i}") for i in range(3)]
    assert codes == [200, 200, 429]
    # And it cannot spend another client's bucket by naming it.
    assert [_attempt("192.0.2.51", "203.0.113.9") for _ in range(2)] == [200, 200]
    assert _attempt(PROXY, "203.0.113.9") == 200


@pytest.mark.parametrize(
    ("trusted", "peer", "forwarded", "expected"),
    [
        ([], "192.0.2.1", "203.0.113.5", "192.0.2.1"),
        ([PROXY], "192.0.2.1", "203.0.113.5", "192.0.2.1"),
        ([PROXY], PROXY, None, PROXY),
        ([PROXY], PROXY, "203.0.113.5", "203.0.113.5"),
        ([PROXY], PROXY, "198.51.100.1, 203.0.113.5", "203.0.113.5"),
        ([PROXY], PROXY, "203.0.113.5:4711", "203.0.113.5"),
        ([PROXY], PROXY, "[2001:db8::7]:443", "2001:db8::7"),
        # Two proxies in a row (a load balancer, then nginx): the one left of both.
        (["10.0.0.0/24", "172.16.0.9"], PROXY, "203.0.113.5, 172.16.0.9", "203.0.113.5"),
        # Every hop a trusted proxy: the earliest one.
        ([PROXY, "10.0.0.2"], PROXY, "10.0.0.2", "10.0.0.2"),
        # Not an address where the client's should be: the proxy's own, never what lies left.
        ([PROXY], PROXY, "203.0.113.5, unknown", PROXY),
        ([PROXY], f"::ffff:{PROXY}", "203.0.113.5", "203.0.113.5"),
    ],
)
def test_the_client_address(settings, trusted, peer, forwarded, expected) -> None:
    settings.RACECRAFT_TRUSTED_PROXIES = trusted
    headers = {"REMOTE_ADDR": peer}
    if forwarded is not None:
        headers["HTTP_X_FORWARDED_FOR"] = forwarded
    assert client_ip(RequestFactory().post(LOGIN, **headers)) == expected


def _listens(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _sign_up_statuses(url: str, forwarded: list[str]) -> list[int]:
    """POSTs to the sign-up page, one per X-Forwarded-For value. They carry no CSRF token:
    counted, then refused with 403, unless the throttle answers 429 first."""
    codes = []
    for value in forwarded:
        headers = {"X-Forwarded-For": value}
        request = urllib.request.Request(
            f"{url}/accounts/signup/", data=b"username=x", headers=headers, method="POST"
        )
        try:
            codes.append(urllib.request.urlopen(request, timeout=30).status)
        except urllib.error.HTTPError as exc:
            codes.append(exc.code)
    return codes


@pytest.mark.parametrize(
    ("trusted", "expected"),
    [
        # The web server passes the connecting address (127.0.0.1) on untouched: a trusted
        # proxy's header splits the buckets ...
        ("127.0.0.1", [403, 403, 429, 403]),
        # ... and an untrusted client's header does not (daphne's --proxy-headers would have
        # believed it: it takes the left-most, client-written address from anyone).
        ("192.0.2.1", [403, 403, 429, 429]),
    ],
)
def test_the_web_server_up_starts(child_env, tmp_path: Path, trusted, expected) -> None:
    port = free_port()
    env = {**child_env, "RACECRAFT_TRUSTED_PROXIES": trusted,
           "RACECRAFT_SIGNUP_RATE": "2/3650d"}  # fmt: skip
    spec = web_spec(ConsoleOptions(host="127.0.0.1", port=port), env)
    with Supervisor(stop_timeout=10) as sup:
        sup.start(spec)
        sup.wait_until(lambda: _listens(port), what="web server", timeout=120)
        url = f"http://127.0.0.1:{port}"
        forwarded = ["203.0.113.5", "203.0.113.5", "198.51.100.1, 203.0.113.5", "203.0.113.6"]
        assert _sign_up_statuses(url, forwarded) == expected
