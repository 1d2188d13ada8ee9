"""Messages go through the Channels layer over the real Redis."""

from __future__ import annotations

import asyncio
import uuid

from channels import DEFAULT_CHANNEL_LAYER
from channels.layers import channel_layers, get_channel_layer
from channels_redis.core import RedisChannelLayer
from django.conf import settings


def test_group_send_reaches_a_member_and_skips_others() -> None:
    assert isinstance(get_channel_layer(), RedisChannelLayer)
    # A layer of its own: the process-wide one keeps receive state and connection pools of
    # the event loops earlier tests ran, which this test's loop must not inherit.
    layer = channel_layers.make_backend(DEFAULT_CHANNEL_LAYER)
    assert isinstance(layer, RedisChannelLayer)
    assert layer.prefix == f"{settings.REDIS_PREFIX}asgi"
    group = f"job-{uuid.uuid4().hex[:8]}"

    async def scenario() -> tuple[dict, bool]:
        member = await layer.new_channel()
        outsider = await layer.new_channel()
        await layer.group_add(group, member)
        await layer.group_send(group, {"type": "job.metrics", "reward": 1.5})
        # Generous: a loaded machine may be slow, never wrong.
        received = await asyncio.wait_for(layer.receive(member), timeout=60)
        try:
            await asyncio.wait_for(layer.receive(outsider), timeout=0.5)
            outsider_got_it = True
        except TimeoutError:
            outsider_got_it = False
        await layer.group_discard(group, member)
        await layer.close_pools()
        return received, outsider_got_it

    received, outsider_got_it = asyncio.run(scenario())
    assert received == {"type": "job.metrics", "reward": 1.5}
    assert outsider_got_it is False
