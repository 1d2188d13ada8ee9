"""The Django project: settings, URLs, ASGI/Celery entry points and the web UI."""

from console.celery import app as celery_app

__all__ = ("celery_app",)
