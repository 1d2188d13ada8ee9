"""Template context shared by every page."""

from __future__ import annotations

from django.conf import settings
from django.http import HttpRequest


def sandbox_warning(request: HttpRequest) -> dict[str, bool]:
    """``sandbox_weak``: the operator accepted weaker reward isolation
    (RACECRAFT_ALLOW_WEAK_SANDBOX), so base.html warns on every page."""
    return {"sandbox_weak": bool(getattr(settings, "RACECRAFT_ALLOW_WEAK_SANDBOX", False))}
