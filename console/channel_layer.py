"""The Channels layer on Redis, with a blocking-read timeout redis-py 8 can live with.

channels_redis waits for messages with ``BZPOPMIN … 5`` (``brpop_timeout = 5`` s), and redis-py 8
gives every connection a default ``socket_timeout`` of 5 s: the client gives up reading at the
very moment the server answers "nothing yet", and every idle websocket consumer dies with
``redis.exceptions.TimeoutError`` after about five seconds. Blocking for 2 s instead keeps the
server's answer well inside the client's timeout.
"""

from __future__ import annotations

from channels_redis.core import RedisChannelLayer
from channels_redis.utils import create_pool

MAX_CONNECTIONS = 1000
"""Redis connections a web process's layer may hold at once. redis-py 8's pool refuses the
101st concurrent command (``MaxConnectionsError``) rather than wait: 500 broadcast viewers
arriving at once (each joining its group) hit that in ``bench/bench_race.py --viewers 500``."""


class RacecraftChannelLayer(RedisChannelLayer):
    brpop_timeout = 2

    def create_pool(self, index):
        return create_pool({"max_connections": MAX_CONNECTIONS, **self.hosts[index]})
