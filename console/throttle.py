"""Throttling of sign-up and log-in with django-ratelimit (a kept library, no code of ours
that counts): too many POSTs from one address (and, for log-in, for one user name) in the
window answer 429 before the view runs, so passwords cannot be guessed at speed nor
accounts made in bulk. The console's log-in page and the admin's count together.

Rates are django-ratelimit's ``"N/period"`` strings from settings (RACECRAFT_LOGIN_RATE,
RACECRAFT_SIGNUP_RATE). Counts live in Django's default cache, which settings point at Redis
(console/redisconf.py ``cache_settings``), so every web process shares one count.

The address is :func:`client_ip` (settings.RATELIMIT_IP_META_KEY): the connecting address,
or behind a trusted reverse proxy (RACECRAFT_TRUSTED_PROXIES) the client's address that the
proxy wrote into X-Forwarded-For.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable
from functools import lru_cache

from django.conf import settings
from django.http import HttpRequest, HttpResponse
from django.urls import reverse
from django_ratelimit.core import ALL, is_ratelimited

TOO_MANY = "Too many attempts from your address; wait a few minutes and try again."
TOO_MANY_LOGINS = (
    "Too many log-in attempts from your address or for this user name; wait a few minutes "
    "and try again."
)
Address = ipaddress.IPv4Address | ipaddress.IPv6Address
Network = ipaddress.IPv4Network | ipaddress.IPv6Network


@lru_cache(maxsize=8)
def _networks(proxies: tuple[str, ...]) -> tuple[Network, ...]:
    return tuple(ipaddress.ip_network(proxy, strict=False) for proxy in proxies)


def _address(text: str) -> Address | None:
    """An address as proxies write it (``1.2.3.4``, ``1.2.3.4:80``, ``[::1]:80``, ``::1``)."""
    text = text.strip()
    if text.startswith("["):
        text = text[1:].partition("]")[0]
    elif text.count(":") == 1:
        text = text.partition(":")[0]
    try:
        address = ipaddress.ip_address(text)
    except ValueError:
        return None
    mapped = getattr(address, "ipv4_mapped", None)
    return mapped or address


def client_ip(request: HttpRequest) -> str:
    """The address a request's rate limits count against.

    The connecting address (REMOTE_ADDR), unless it is one of RACECRAFT_TRUSTED_PROXIES: then
    X-Forwarded-For is read from the right, skipping trusted proxies, and the first other
    address is the client's. Everything left of it was written by the client and may be
    forged, so it is never read; an entry that is not an address stops the walk there."""
    peer = request.META.get("REMOTE_ADDR", "")
    trusted = _networks(tuple(settings.RACECRAFT_TRUSTED_PROXIES))

    def is_trusted(address: Address | None) -> bool:
        return address is not None and any(address in network for network in trusted)

    if not is_trusted(_address(peer)):
        return peer
    client = peer
    for hop in reversed(request.META.get("HTTP_X_FORWARDED_FOR", "").split(",")):
        address = _address(hop)
        if address is None:
            break
        client = str(address)
        if not is_trusted(address):
            break
    return client


def _limited(request: HttpRequest, group: str, key: str, rate: str) -> bool:
    return is_ratelimited(request, group=group, key=key, rate=rate, method="POST", increment=True)


def login_key(group: str, request: HttpRequest) -> str:
    """The user name tried, so one account is protected from many addresses too."""
    return str(request.POST.get("username", "")).strip().lower()[:150]


TOO_MANY_PREVIEWS = "Too many layout previews from your address; wait a minute and try again."


def previews_limited(request: HttpRequest) -> bool:
    """Whether this address asked for more race layout pictures than RACECRAFT_PREVIEW_RATE
    (each one is drawn on request, so a flood would keep a web process busy)."""
    return is_ratelimited(request, group="race-preview", key="ip",
                          rate=settings.RACECRAFT_PREVIEW_RATE, method=ALL,
                          increment=True)  # fmt: skip


class ThrottleMiddleware:
    """429 for POSTs to the sign-up and log-in pages over their rates."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        refusal = self._over(request) if request.method == "POST" else None
        if refusal:
            return HttpResponse(refusal, status=429, content_type="text/plain; charset=utf-8")
        return self.get_response(request)

    @staticmethod
    def _over(request: HttpRequest) -> str | None:
        """The refusal in words when this POST is over its rate, else None."""
        if request.path == reverse("signup"):
            over = _limited(request, "signup", "ip", settings.RACECRAFT_SIGNUP_RATE)
            return TOO_MANY if over else None
        # The admin's log-in page takes the same passwords: one count for both pages.
        if request.path in (reverse("login"), reverse("admin:login")):
            rate = settings.RACECRAFT_LOGIN_RATE
            by_ip = _limited(request, "login-ip", "ip", rate)
            by_user = _limited(request, "login-user", "console.throttle.login_key", rate)
            return TOO_MANY_LOGINS if by_ip or by_user else None
        return None
