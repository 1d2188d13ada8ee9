"""The broadcast hub's fan-out through a real daphne (:class:`leaderboard.broadcast.Wire`): two
anonymous viewers of a public event on raw websockets, one reading, one that stops reading (a
viewer on a slow network: its socket fills). The reading one gets every frame; the stalled one
gets the frames its connection took before it filled, none queued behind them, and once it
reads again the newest frame next, whole. Frames are 1 MB so that the stalled connection fills
after a few (the kernel's socket buffers hold a few MB). Nothing is timed."""

from __future__ import annotations

import base64
import os
import socket
import time

import pytest
import redis
from django.conf import settings
from league_helpers import make_event

from leaderboard.live import broadcast_group
from racing.framecodec import decode_header, encode_frame
from training import live

pytestmark = [pytest.mark.slow, pytest.mark.django_db(transaction=True)]
WAIT_S = 60.0
"""The most the test waits for something that takes milliseconds."""
PICTURE = b"\xff\xd8" + bytes(1 << 20) + b"\xff\xd9"


class Viewer:
    """A raw websocket client (RFC 6455), as bench/bench_race.py's viewers: the clock of every
    whole frame message it read."""

    def __init__(self, port: int, path: str, *, receive_buffer: int = 0) -> None:
        self.sock = socket.socket()
        if receive_buffer:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                          "Upgrade: websocket\r\nConnection: Upgrade\r\n"
                          f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                          f"Origin: http://127.0.0.1:{port}\r\n\r\n".encode())  # fmt: skip
        self.data = bytearray()
        self.sock.settimeout(WAIT_S)
        while b"\r\n\r\n" not in self.data:
            chunk = self.sock.recv(65536)
            assert chunk, "closed during the handshake"
            self.data += chunk
        head, _, rest = bytes(self.data).partition(b"\r\n\r\n")
        assert b" 101 " in head.split(b"\r\n", 1)[0], head
        self.data = bytearray(rest)
        self.clocks: list[float] = []

    def _parse(self) -> None:
        while len(self.data) >= 2:
            length, at = self.data[1] & 0x7F, 2
            if length >= 126:
                size = 2 if length == 126 else 8
                if len(self.data) < at + size:
                    return
                length, at = int.from_bytes(self.data[at : at + size], "big"), at + size
            if len(self.data) < at + length:
                return
            if self.data[0] & 0x0F == 0x2:
                header = decode_header(bytes(self.data[at : at + length]))[0]
                self.clocks.append(header["timing"]["clock_s"])
            del self.data[: at + length]

    def read(self, wait_s: float) -> None:
        """Whatever arrives within ``wait_s`` seconds of quiet."""
        self.sock.settimeout(wait_s)
        try:
            while chunk := self.sock.recv(1 << 20):
                self.data += chunk
                self._parse()
        except TimeoutError:
            pass

    def read_until(self, clock_s: float) -> None:
        deadline = time.monotonic() + WAIT_S
        while clock_s not in self.clocks:
            assert time.monotonic() < deadline, f"no frame {clock_s} (got {self.clocks[-3:]})"
            self.read(0.2)


def test_a_viewer_whose_socket_fills_skips_frames_then_gets_the_newest_whole(fran, daphne):
    event = make_event(fran, is_private=False)
    port = int(daphne.url.rsplit(":", 1)[1])
    path = f"/ws/league/events/{event.pk}/broadcast/"
    channel = live.broadcast_channel(broadcast_group(event.pk))
    reading = Viewer(port, path)
    stalled = Viewer(port, path, receive_buffer=4096)
    client = redis.Redis.from_url(settings.REDIS_URL)
    try:
        deadline = time.monotonic() + WAIT_S
        while not client.pubsub_numsub(channel)[0][1]:  # daphne's hub has subscribed
            assert time.monotonic() < deadline, daphne.log()[-2000:]
            time.sleep(0.05)
        published: list[float] = []
        for step in range(16):  # 16 MB: more than the stalled connection holds
            clock = step / 15
            client.publish(channel, encode_frame({"timing": {"clock_s": clock}}, PICTURE))
            published.append(clock)
            reading.read_until(clock)  # written to everyone before the next one comes
        step = 16
        while not stalled.clocks or stalled.clocks[-1] != published[-1]:
            assert time.monotonic() < deadline + WAIT_S, stalled.clocks
            stalled.read(0.2)  # it reads again: what its connection held, then the newest
            clock = step / 15
            client.publish(channel, encode_frame({"timing": {"clock_s": clock}}, PICTURE))
            published.append(clock)
            reading.read_until(clock)
            stalled.read(0.2)
            step += 1
    finally:
        client.close()
        reading.sock.close()
        stalled.sock.close()
    assert reading.clocks == published  # every frame, in order, to the viewer who reads
    got = stalled.clocks
    assert got == sorted(got) and len(set(got)) == len(got)  # in order, none twice
    assert got[-1] == published[-1]  # the newest
    skipped = [clock for clock in published[:16] if clock not in got]
    assert skipped, "the stalled viewer was sent every frame: they queued behind its socket"
