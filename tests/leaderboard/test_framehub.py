"""A web process's broadcast hub (:class:`leaderboard.broadcast.FrameHub`) on the tests' real
Redis: a viewer that is slow to take its frames (a loaded machine, a slow network) gets the
newest frame next, however old the frames are by the wall clock (a loaded worker, or one whose
clock is behind), and skips the ones in between; a frame that cannot be read never goes out."""

from __future__ import annotations

import asyncio
import time

import redis.asyncio as aioredis
from asgiref.sync import async_to_sync
from django.conf import settings

from leaderboard.broadcast import FrameHub
from racing.framecodec import decode_frame, encode_frame
from training import live

WAIT_S = 30.0
"""How long the test waits, at the most, for something that happens in milliseconds."""


class SlowViewer:
    """A viewer whose first frame takes until :attr:`release` is set to write."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.release = asyncio.Event()
        self.got = asyncio.Event()

    async def send(self, bytes_data: bytes) -> None:
        self.frames.append(bytes_data)
        self.got.set()
        await self.release.wait()


def frame(clock_s: float, built_at: float) -> bytes:
    return encode_frame({"timing": {"clock_s": clock_s}, "t": built_at}, b"\xff\xd8" + bytes(8))


async def until(condition) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, "the hub did not get there"
        await asyncio.sleep(0.01)


def test_a_delayed_viewer_gets_the_newest_frame_however_old_the_frames_are():
    channel = live.broadcast_channel("race-framehub-test")
    minute_ago = time.time() - 60  # by the wall clock, every frame is a minute old

    async def scenario() -> tuple[list[bytes], int]:
        viewer = SlowViewer()
        FrameHub.join(channel, viewer)
        publisher = aioredis.Redis.from_url(settings.REDIS_URL)
        try:
            await until(lambda: channel in FrameHub.newest)
            newest = FrameHub.newest[channel]
            while not (await publisher.pubsub_numsub(channel))[0][1]:
                await asyncio.sleep(0.01)
            await publisher.publish(channel, frame(0.0, minute_ago))
            await asyncio.wait_for(viewer.got.wait(), WAIT_S)  # now writing it, slowly
            await publisher.publish(channel, b"\x00\x00\x00\x05{nope")  # unreadable
            for step in range(1, 10):
                await publisher.publish(channel, frame(step / 15, minute_ago + step / 15))
            await publisher.publish(channel, b"garbage")
            await until(lambda: newest.frame is not None and newest.skipped == 8)
            viewer.got.clear()
            viewer.release.set()
            await asyncio.wait_for(viewer.got.wait(), WAIT_S)
            return viewer.frames, newest.skipped
        finally:
            await publisher.aclose()
            FrameHub.leave(channel, viewer)

    frames, skipped = async_to_sync(scenario)()
    clocks = [decode_frame(f)[0]["timing"]["clock_s"] for f in frames]
    assert clocks == [0.0, 9 / 15]  # the first, then straight to the newest: 8 skipped
    assert skipped == 8
    assert channel not in FrameHub.tasks
