"""One Redis URL, turned into what each client wants.

REDIS_URL uses redis-py's forms: ``redis://host:port/db``, ``rediss://...`` or
``unix:///path/to/redis.sock?db=N`` (the embedded Redis). redis-py and channels_redis
read all of them; Celery (kombu) spells a unix socket ``redis+socket:///path?virtual_host=N``.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import parse_qs, urlencode, urlsplit


def celery_url(redis_url: str) -> str:
    """The Celery broker/result-backend URL for ``redis_url``.

    >>> celery_url("unix:///tmp/r.sock?db=3")
    'redis+socket:///tmp/r.sock?virtual_host=3'
    """
    parts = urlsplit(redis_url)
    if parts.scheme != "unix":
        return redis_url
    query = parse_qs(parts.query)
    db = query.pop("db", ["0"])[-1]
    params = {key: values[-1] for key, values in query.items()}
    params["virtual_host"] = db
    return f"redis+socket://{parts.path}?{urlencode(params)}"


def channel_layers(redis_url: str, prefix: str) -> dict[str, Any]:
    """The CHANNEL_LAYERS setting: channels_redis on ``redis_url``, keys under ``prefix``."""
    return {
        "default": {
            "BACKEND": "console.channel_layer.RacecraftChannelLayer",
            "CONFIG": {"hosts": [redis_url], "prefix": f"{prefix}asgi"},
        }
    }


def cache_settings(redis_url: str, prefix: str) -> dict[str, Any]:
    """The CACHES setting: Django's Redis cache on ``redis_url``, keys under ``prefix``. The
    throttles (django-ratelimit) count in this cache, so every web process shares one count:
    a per-process cache would let each of N processes allow the full rate."""
    return {
        "default": {
            "BACKEND": "django.core.cache.backends.redis.RedisCache",
            "LOCATION": redis_url,
            "KEY_PREFIX": f"{prefix}cache",
        }
    }


def celery_settings(redis_url: str, prefix: str) -> dict[str, Any]:
    """The CELERY_* settings that depend on Redis, every key under ``prefix``."""
    url = celery_url(redis_url)
    options: dict[str, Any] = {"global_keyprefix": prefix} if prefix else {}
    return {
        "CELERY_BROKER_URL": url,
        "CELERY_RESULT_BACKEND": url,
        "CELERY_BROKER_TRANSPORT_OPTIONS": dict(options),
        "CELERY_RESULT_BACKEND_TRANSPORT_OPTIONS": dict(options),
    }
