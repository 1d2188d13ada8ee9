"""Throttling of sign-up and log-in with django-ratelimit (a kept library, no code of ours
that counts): too many POSTs from one address (and, for log-in, for one user name) in the
window answer 429 before the view runs, so passwords cannot be guessed at speed nor
accounts made in bulk.

Rates are django-ratelimit's ``"N/period"`` strings from settings (RACECRAFT_LOGIN_RATE,
RACECRAFT_SIGNUP_RATE). Counts live in Django's default cache, which settings point at Redis
(console/redisconf.py ``cache_settings``), so every web process shares one count.
"""

from __future__ import annotations

from collections.abc import Callable

from django.conf import settings
from django.http import HttpRequest, HttpResponse
from django.urls import reverse
from django_ratelimit.core import ALL, is_ratelimited

TOO_MANY = "Too many attempts from your address; wait a few minutes and try again."


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
        if request.method == "POST" and self._over(request):
            return HttpResponse(TOO_MANY, status=429, content_type="text/plain")
        return self.get_response(request)

    @staticmethod
    def _over(request: HttpRequest) -> bool:
        if request.path == reverse("signup"):
            return _limited(request, "signup", "ip", settings.RACECRAFT_SIGNUP_RATE)
        if request.path == reverse("login"):
            rate = settings.RACECRAFT_LOGIN_RATE
            by_ip = _limited(request, "login-ip", "ip", rate)
            by_user = _limited(request, "login-user", "console.throttle.login_key", rate)
            return by_ip or by_user
        return False
