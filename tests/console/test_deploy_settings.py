"""Production settings: `manage.py check --deploy` is clean with DEBUG off, cookies are secure,
and every page carries a Content Security Policy that allows no inline script."""

from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PRODUCTION = {
    "DEBUG": "0",
    "SECRET_KEY": secrets.token_urlsafe(64),
    "ALLOWED_HOSTS": "racecraft.example.com",
}


def manage(*args: str, **overrides: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DEBUG", "SECRET_KEY")}
    env.update(PRODUCTION | overrides)
    return subprocess.run([sys.executable, "manage.py", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=180)  # fmt: skip


@pytest.mark.slow
def test_check_deploy_is_clean_with_debug_off() -> None:
    result = manage("check", "--deploy", "--fail-level", "WARNING")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "WARNINGS" not in result.stdout and "ERRORS" not in result.stdout


@pytest.mark.parametrize("key", ["django-insecure-racecraft-dev-only", ""])
def test_debug_off_refuses_to_start_with_the_development_key_or_none(key: str) -> None:
    """No public key ever signs a production console's cookies: `up` (here `check`, which
    loads the same settings) stops before anything is served, saying what to set."""
    result = manage("check", SECRET_KEY=key)
    assert result.returncode != 0
    assert "ImproperlyConfigured: SECRET_KEY must be set to a long random value when DEBUG=0" \
        in result.stderr  # fmt: skip
    assert "secrets.token_urlsafe(64)" in result.stderr


@pytest.mark.slow
def test_cookies_are_secure_and_hsts_is_on_with_debug_off() -> None:
    code = (
        "import json; from django.conf import settings as s; print(json.dumps(["
        "s.SESSION_COOKIE_SECURE, s.CSRF_COOKIE_SECURE, s.SECURE_HSTS_SECONDS,"
        " list(s.SECURE_PROXY_SSL_HEADER)]))"
    )
    result = manage("shell", "-c", code)
    assert result.returncode == 0, result.stderr
    secure_session, secure_csrf, hsts, proxy = json.loads(result.stdout.strip().splitlines()[-1])
    assert secure_session and secure_csrf and hsts >= 31_536_000
    assert proxy == ["HTTP_X_FORWARDED_PROTO", "https"]


@pytest.mark.django_db
def test_pages_carry_a_policy_without_inline_scripts(client) -> None:
    policy = client.get("/").headers["Content-Security-Policy"]
    assert (
        "script-src 'self'" in policy
        and "'unsafe-inline'" not in policy.split("script-src")[1].split(";")[0]
    )
    assert "frame-ancestors 'none'" in policy


def test_templates_have_no_inline_event_handlers() -> None:
    offenders = [
        str(path.relative_to(ROOT))
        for path in (ROOT / "templates").rglob("*.html")
        if any(
            f" on{event}=" in path.read_text() for event in ("click", "submit", "change", "load")
        )
    ]
    assert offenders == []


@pytest.mark.parametrize("host", ["0.0.0.0", "192.0.2.7", "::", "racecraft.example.com"])
def test_up_refuses_an_open_address_with_debug_on(host) -> None:
    from django.core.management.base import CommandError

    from console.management.commands.up import refuse_debug_on_open_address

    with pytest.raises(CommandError, match="with DEBUG on"):
        refuse_debug_on_open_address(host, debug=True)
    refuse_debug_on_open_address(host, debug=False)  # production settings: allowed


@pytest.mark.parametrize("host", ["127.0.0.1", "::1", "[::1]", "localhost", "127.0.0.2"])
def test_up_listens_on_loopback_with_debug_on(host) -> None:
    from console.management.commands.up import refuse_debug_on_open_address

    assert refuse_debug_on_open_address(host, debug=True) is None
