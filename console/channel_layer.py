"""The Channels layer on Redis, with a blocking-read timeout redis-py 8 can live with.

channels_redis waits for messages with ``BZPOPMIN … 5`` (``brpop_timeout = 5`` s), and redis-py 8
gives every connection a default ``socket_timeout`` of 5 s: the client gives up reading at the
very moment the server answers "nothing yet", and every idle websocket consumer dies with
``redis.exceptions.TimeoutError`` after about five seconds. Blocking for 2 s instead keeps the
server's answer well inside the client's timeout.
"""

from __future__ import annotations

from channels_redis.core import RedisChannelLayer


class RacecraftChannelLayer(RedisChannelLayer):
    brpop_timeout = 2
