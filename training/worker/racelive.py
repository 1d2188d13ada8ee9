"""A race's live broadcast: each broadcast frame encoded once as a JPEG, with its header (the
step's timing: clock, laps, positions, gaps, sectors; the TV camera's shot; where the PiPs and
the map lie: :meth:`racing.broadcast.BroadcastView.header`), and published once to the race's
broadcast channel (:class:`training.live.BroadcastPublisher`) however many people watch;
paced at real time for a live race day.

A frame goes out as one binary websocket message in the one frame format
(:func:`racing.framecodec.encode_frame`: a 4-byte big-endian length, the JSON header with
``"t"``, the unix time it was built, then the JPEG). Each web process forwards it untouched to
its viewers (no per-viewer encoding, no base64), always the newest frame it has
(:class:`leaderboard.broadcast.FrameHub`), so a lagging process falls behind by frames, never
by seconds, and never goes dark (``t`` is for measuring; nothing is dropped by its age).

Frames are encoded only while someone watches the race (or a race day paces it); a background
sender skips to the newest frame rather than slow the race
(:class:`training.live.BroadcastPublisher`).
"""

from __future__ import annotations

import io
import time

import numpy as np
from PIL import Image

from racing.framecodec import encode_frame
from training import live

JPEG_QUALITY = 70
FRAME_S = 1.0 / 15.0
"""A frame of race clock: paced races show one every 1/15 s of wall time."""


class RaceBroadcast:
    """``frame(rgb, header)`` for :func:`training.rl.race.run_race`'s ``on_frame``: each frame
    encoded once and sent to every group in ``groups`` (the race's own, a race day's)."""

    def __init__(self, groups: list[str], *, paced: bool = False) -> None:
        self.groups = groups
        self.paced = paced
        self.publishers = [live.BroadcastPublisher(group) for group in groups]
        self._next = time.monotonic()
        self.encodes = 0
        self.frames = 0

    def frame(self, rgb: np.ndarray, header: dict) -> None:
        if self.paced:
            self._next += FRAME_S
            wait = self._next - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            else:
                self._next = time.monotonic()  # behind: never race to catch up
        self.frames += 1
        if not (self.paced or any(p.watched() for p in self.publishers)):
            return
        buffer = io.BytesIO()  # Pillow's libjpeg-turbo: about half OpenCV's time here
        Image.fromarray(rgb).save(buffer, "JPEG", quality=JPEG_QUALITY)
        self.encodes += 1
        payload = encode_frame({**header, "t": round(time.time(), 3)}, buffer.getvalue())
        for publisher in self.publishers:
            publisher.offer(payload)

    def close(self) -> None:
        for publisher in self.publishers:
            publisher.close()
