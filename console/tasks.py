"""Tasks of the console itself."""

from __future__ import annotations

from celery import shared_task


@shared_task(name="console.tasks.ping")
def ping(payload: str = "pong") -> str:
    """Echo ``payload``: proves a worker is consuming the default queue."""
    return payload
