"""A race's live broadcast: each broadcast frame encoded once as a JPEG, with the timing
(clock, laps, positions, sector colours), and published once to the race's broadcast channel
(:class:`training.live.BroadcastPublisher`) however many people watch; paced at real time for
a live race day.

A frame goes out as one binary websocket message, built here once for every viewer
(:func:`frame_payload`): a 4-byte big-endian length, that many bytes of JSON (``{"timing":
..., "t": <unix time>}``), then the JPEG. Each web process forwards it untouched to its
viewers (no per-viewer encoding, no base64) and drops a frame that is already stale, so a
lagging process falls behind by frames, never by seconds.

Frames are encoded only while someone watches the race (or a race day paces it); a background
sender drops a stale frame rather than slow the race (:class:`training.live.BroadcastPublisher`).
"""

from __future__ import annotations

import io
import json
import struct
import time

import numpy as np
from PIL import Image

from racing.headtohead import CarState, HeadToHeadRace
from racing.racecar import sector_colours
from training import live

JPEG_QUALITY = 70
FRAME_S = 1.0 / 15.0
"""A frame of race clock: paced races show one every 1/15 s of wall time."""


def race_timing(race: HeadToHeadRace) -> dict:
    """What the broadcast page shows beside the video, as plain JSON types."""
    colours = sector_colours(race.cars)
    cars = []
    for position, car in enumerate(race.standings(), start=1):
        done = [lap.time_s for lap in car.tracker.laps]
        current = car.lap_sectors or (car.sectors[-1] if car.sectors else [])
        cars.append({
            "index": car.index,
            "name": car.racer.name or f"Car {car.index + 1}",
            "colour": "#{:02x}{:02x}{:02x}".format(*car.colour),
            "position": position,
            "lap": min(race.rules.laps, car.laps_done + (car.state is not CarState.FINISHED)),
            "laps_done": car.laps_done,
            "state": car.state.value,
            "reason": car.reason,
            "lap_time_s": round(car.tracker.sim_time - car.tracker.lap_start_time, 2)
            if car.state is CarState.RACING else None,
            "last_lap_s": round(done[-1], 3) if done else None,
            "best_lap_s": round(min(done), 3) if done else None,
            "sectors": [round(t, 2) for t in current],
            "sector_colours": colours.get(car.index, []),
            "finish_s": None if car.finish_time_s is None else round(car.finish_time_s, 3),
        })  # fmt: skip
    return {"clock_s": round(race.clock_s, 2), "laps": race.rules.laps, "over": race.over,
            "cars": cars}  # fmt: skip


def frame_payload(jpeg: bytes, timing: dict, sent_at: float) -> bytes:
    """One frame as the broadcast page receives it (see the module docstring)."""
    header = json.dumps({"timing": timing, "t": round(sent_at, 3)},
                        separators=(",", ":")).encode()  # fmt: skip
    return struct.pack("!I", len(header)) + header + jpeg


def read_frame_payload(payload: bytes) -> tuple[dict, bytes]:
    """``(header, jpeg)`` of a frame message (for tests and benchmarks)."""
    (length,) = struct.unpack("!I", payload[:4])
    return json.loads(payload[4 : 4 + length]), payload[4 + length :]


class RaceBroadcast:
    """``frame(rgb, race)`` for :func:`training.rl.race.run_race`'s ``on_frame``: each frame
    encoded once and sent to every group in ``groups`` (the race's own, a race day's)."""

    def __init__(self, groups: list[str], *, paced: bool = False) -> None:
        self.groups = groups
        self.paced = paced
        self.publishers = [live.BroadcastPublisher(group) for group in groups]
        self._next = time.monotonic()
        self.encodes = 0
        self.frames = 0

    def frame(self, rgb: np.ndarray, race: HeadToHeadRace) -> None:
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
        payload = frame_payload(buffer.getvalue(), race_timing(race), time.time())
        for publisher in self.publishers:
            publisher.offer(payload)

    def close(self) -> None:
        for publisher in self.publishers:
            publisher.close()
