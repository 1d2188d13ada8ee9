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


class FakeWire:
    """A viewer's daphne websocket, as :class:`leaderboard.broadcast.Wire` is to the hub:
    backed up (its socket still holding an earlier frame) while :attr:`held` is set."""

    prepared = 0

    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.held = False

    def backed_up(self) -> bool:
        return self.held

    def prepare(self, frame: bytes) -> bytes:
        FakeWire.prepared += 1
        return b"framed:" + frame

    def write(self, prepared: bytes) -> None:
        self.frames.append(prepared.removeprefix(b"framed:"))


class WiredViewer:
    def __init__(self) -> None:
        self.wire = FakeWire()

    async def send(self, bytes_data: bytes) -> None:  # never used: the hub writes to the wire
        raise AssertionError("a wired viewer's frames go to its wire")


class PlainViewer:
    """A viewer without a daphne socket under it: its consumer's ``send``."""

    def __init__(self, on_send=None) -> None:
        self.frames: list[bytes] = []
        self.on_send = on_send

    async def send(self, bytes_data: bytes) -> None:
        self.frames.append(bytes_data)
        if self.on_send is not None:
            self.on_send()


def clocks(frames: list[bytes]) -> list[float]:
    return [decode_frame(f)[0]["timing"]["clock_s"] for f in frames]


def test_a_backed_up_viewer_skips_frames_gets_the_newest_next_and_holds_nobody_up(monkeypatch):
    """Each frame is framed once for all wired viewers; a viewer whose socket still holds an
    earlier frame is skipped (no queue), gets the newest frame once it has taken the last one,
    and the others get every frame meanwhile."""
    from leaderboard import broadcast

    monkeypatch.setattr(broadcast, "wire_of", lambda viewer: getattr(viewer, "wire", None))
    channel = "racecraft:broadcast:fan-out-test"
    fast, slow, plain = WiredViewer(), WiredViewer(), PlainViewer()
    FrameHub.viewers[channel] = dict.fromkeys([fast, slow, plain])
    FakeWire.prepared = 0
    frames = [frame(step / 15, 0.0) for step in range(6)]

    async def scenario() -> None:
        for step, data in enumerate(frames):
            slow.wire.held = step in (1, 2, 3)  # its connection holds frame 0 until frame 4
            await FrameHub.fan_out(channel, data)

    try:
        async_to_sync(scenario)()
    finally:
        FrameHub.viewers.pop(channel, None)
    every = [step / 15 for step in range(6)]
    assert clocks(fast.wire.frames) == every
    assert clocks(plain.frames) == every
    assert clocks(slow.wire.frames) == [0.0, 4 / 15, 5 / 15]  # 1-3 skipped, then the newest
    assert slow.frames_skipped == 3 and not hasattr(fast, "frames_skipped")
    assert FakeWire.prepared == 6  # once a frame, however many viewers


def test_a_viewer_that_left_while_a_frame_went_out_gets_nothing_after_it_left(monkeypatch):
    """Revoked viewers stop at once: one that leaves the hub while an earlier viewer's send of
    the same frame is under way does not get that frame, wired or not."""
    from leaderboard import broadcast

    monkeypatch.setattr(broadcast, "wire_of", lambda viewer: getattr(viewer, "wire", None))
    channel = "racecraft:broadcast:leave-test"
    revoked_wired, revoked_plain = WiredViewer(), PlainViewer()

    def revoke() -> None:
        FrameHub.viewers[channel].pop(revoked_wired)
        FrameHub.viewers[channel].pop(revoked_plain)

    first = PlainViewer(on_send=revoke)  # its send is under way when the others are revoked
    FrameHub.viewers[channel] = dict.fromkeys([first, revoked_wired, revoked_plain])

    async def scenario() -> None:
        await FrameHub.fan_out(channel, frame(0.0, 0.0))
        await FrameHub.fan_out(channel, frame(1 / 15, 0.0))

    try:
        async_to_sync(scenario)()
    finally:
        FrameHub.viewers.pop(channel, None)
    assert clocks(first.frames) == [0.0, 1 / 15]
    assert revoked_wired.wire.frames == [] and revoked_plain.frames == []
