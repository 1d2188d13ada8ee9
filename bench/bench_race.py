"""A live race day as its spectators get it: a 2-car (``--cars`` 1-4) head-to-bot race with 6
bots, broadcast at real time to 100 (``--viewers``) websocket viewers of a public event, all on
this machine.

    .venv/bin/python bench/bench_race.py [--cars 2] [--viewers 100] [--seconds 30] [--seeds 1]
                                         [--track racecraft_oval] [--penalty-s 0]
                                         [--no-video] [--redis-url URL]

The issue's goal: ``--cars 4 --viewers 500``.

The cars are what a user gets with the console's defaults: untrained PPO models on the
network :func:`training.services.models.model_create` picks by default, DeepRacer's default
discrete action space (:data:`racing.actions.DEFAULT_DISCRETE`); car 1 has the front camera,
car 2 stereo cameras and LIDAR (DeepRacer's guidance for head-to-head racing), cars 3 and 4
(``--cars 4``) the front camera and stereo cameras. 6 bots drive at
0.75 m/s. Torch runs one thread, as in the worker. The penalties are 0 s by default: untrained
cars leave the track every few seconds, and with DeepRacer's 5 s (``--penalty-s 5``) they
would sit out most of the race, neither simulated nor asking their policy; at 0 s both drive
every step, as trained cars that stay on track do (``driven`` counts the car-steps).

Each seed races twice in this process, for ``--seconds`` of race clock each (stopped after
``--seconds`` x 15 steps: a race's own time limit is at least 10 s):

- **unpaced** (the baseline): nobody watches, no video: the simulation and the policies as fast
  as they go (``steps/s``);
- **live**: as a race day's evaluation worker runs it (:func:`training.worker.race.run_race_job`):
  :class:`training.worker.racelive.RaceBroadcast` paced at real time (15 frames/s), each
  1280x720 frame (the TV camera following the director's car, the track map and one
  picture-in-picture per car: :class:`racing.broadcast.BroadcastView`) JPEG-encoded once and
  sent once to the event's broadcast group, the MP4 (its timing burnt in)
  recorded (``--no-video``: not), while ``--spectators`` websocket clients (one child process,
  asyncio, raw RFC 6455: they time each frame message and read its race clock, nothing else;
  see the viewers below) watch ``/ws/league/events/<id>/broadcast/`` as anonymous visitors
  of a public event, through
  a real daphne started as ``manage.py up`` starts it (its listen queue and handshake timeout:
  :func:`console.launcher.daphne_server_args`) serving ``console.asgi`` and a Channels layer on
  Redis (an embedded Redis
  unless ``--redis-url``; every key under a random prefix, deleted at the end). The database
  is a fresh SQLite file in a temporary folder (the event and its organiser; nothing else
  touches it during the race). They arrive 10 every 50 ms; a viewer whose connection fails
  tries again as the page does (after 1 s, then 2 s, 4 s: ``static/leaderboard/broadcast.js``),
  :data:`CONNECT_TRIES` times in all. After the race the viewers listen on until the frames
  stop.

The viewers stand for browsers on other machines, so they do no more than a browser must to
show the frame's time: each is an asyncio ``BufferedProtocol`` (:class:`ViewerProtocol`)
whose socket reads into its own buffer (``recv_into``); every message is parsed where it
lies, and every frame message is timed when its last byte is read and its header decoded
with the one frame decoder for its race clock; the picture is neither copied nor decoded.
Before (issue 48's first measurements) each viewer was a ``StreamReader`` coroutine whose
``readexactly`` copied each 50 KB message three times (into the reader's buffer, out of it,
and the rest of the buffer moved down), and timed it when the coroutine next ran; and the
header's depth check walked its 1.7 KB byte by byte in Python (now in C:
:func:`racing.framecodec.decode_header`, the same for every reader): together about 60% of
the viewers' CPU. They receive, time and read the same messages as before.

The window of a live race starts 1 s after its first frame (the first second is left out) and
ends when the race returns. Per viewer: frames received in the window, frames/s over it, the
longest gap between two frames (the gap from its last frame to the window's end included),
every frame it got (late ones too), and the delay from the race showing a frame to the viewer
getting it. Printed: the table per seed and run, the cars' outcomes (the same race both times:
checked), the CPU seconds of each process during the live race (race, daphne, viewers, the
embedded Redis, and the whole machine: other work shows there) and the machine (CPU, cores,
load average before and after). The viewers share this machine's cores with the race and
daphne; on a real race day they are elsewhere.

Last line (medians over the seeds, worst gap over all): ``race_fps=`` frames/s delivered to the
median viewer (target >= 14), ``paced_fps=`` frames/s the race itself showed, ``max_gap_s=``
(target <= 1.0), ``encodes_per_frame=`` JPEG encodes / frames shown (<= 1.05: one encode
however many watch), ``sim_steps_per_s=`` the unpaced race's steps per second of wall time,
``realtime=`` race_fps / 15, ``ratio=`` the live race's CPU per step over the unpaced one's,
both measured in this run (what broadcasting, the MP4 and pacing cost the worker),
``race_cpu_ms_per_frame=`` the race process's CPU per frame shown,
``daphne_cpu_us_per_delivery=`` and ``viewers_cpu_us_per_delivery=`` daphne's and the viewers'
CPU per frame message delivered (one frame to one viewer; machine-independent units, unlike
the frames/s of a shared machine),
``delay_s=`` the median viewer's median delay behind the race, ``frames_per_viewer=`` (in the
window), ``spectators=`` connected/asked and ``retried=`` how many of them connected only after
a failed try. Steps and frames do not depend on the machine;
wall times, frames/s, gaps and delays do. The machine may be shared: say so when you quote the
figures.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import os
import secrets
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

ROOT = Path(__file__).resolve().parents[1]
REALTIME_FPS = 15.0
"""Frames (and steps) per second of a race shown at real time: racelive.FRAME_S's inverse."""
SETTLE_S = 1.0
"""Seconds after the first frame left out of the window."""
QUIET_S, MAX_DRAIN_S = 1.0, 60.0
"""After the race the viewers listen on until no frame came for QUIET_S (frames in flight or
queued), MAX_DRAIN_S at most."""
CONNECT_TIMEOUT_S = 90.0
CONNECT_TRIES = 4
"""A viewer's tries to connect, 1 s, 2 s and 4 s apart (as the broadcast page retries)."""
START_TIMEOUT_S = 90.0
CARS = (("FRONT_FACING_CAMERA",), ("STEREO_CAMERAS", "LIDAR"), ("FRONT_FACING_CAMERA",),
        ("STEREO_CAMERAS",))  # fmt: skip
BOTS, BOT_SPEED_MPS = 6, 0.75
READY = "READY"


# ---------------------------------------------------------------------------- the figures
@dataclass
class Viewer:
    """One viewer: frames in the window, frames/s over it and the longest gap (seconds); all
    the frames it got, the race in time and after; how long after the race showed them (s)."""

    frames: int
    fps: float
    max_gap_s: float
    received: int
    delay_median_s: float
    delay_max_s: float


def viewer_window(arrivals: list[tuple[float, float | None]], start: float, end: float,
                  shown_at: dict[float, float]) -> Viewer:  # fmt: skip
    """A viewer's frames (``(monotonic arrival, race clock)`` each) in the window ``[start,
    end]``: how many, per second, and the longest gap between two of them; the gap from its
    last frame to ``end`` counts, and so does the one that runs into the window from before it
    (or from ``start``). Delays: from ``shown_at[race clock]`` (when the race showed that
    frame) to the arrival, for every frame shown from ``start`` on."""
    times = [t for t, _ in arrivals]
    inside = [t for t in times if start <= t <= end]
    before = [t for t in times if t < start]
    points = [before[-1] if before else start, *inside, end]
    gaps = [b - a for a, b in zip(points, points[1:], strict=False)]
    span = end - start
    delays = [t - shown_at[c] for t, c in arrivals
              if c is not None and shown_at.get(c, -1.0) >= start]  # fmt: skip
    return Viewer(
        frames=len(inside), fps=len(inside) / span if span > 0 else 0.0,
        max_gap_s=max(gaps, default=span), received=len(arrivals),
        delay_median_s=median(delays), delay_max_s=max(delays, default=float("nan")),
    )  # fmt: skip


@dataclass
class Live:
    """The live run's viewers and broadcast."""

    viewers: list[Viewer]
    connected: int
    wanted: int
    frames: int
    encodes: int
    sent: int
    window_s: float
    shown_s: float
    """Wall seconds from the first frame the race showed to its last."""
    cpu_s: dict[str, float] = field(default_factory=dict)
    """CPU seconds during the race per process, and ``machine`` (every process, both cores)."""
    retried: int = 0
    """Viewers that connected only after a failed try."""

    @property
    def paced_fps(self) -> float:
        """Frames/s the race itself showed (its pacing), first frame to last."""
        return (self.frames - 1) / self.shown_s if self.shown_s > 0 else 0.0

    @property
    def fps(self) -> float:
        """Frames/s of the median viewer (0 when none connected)."""
        return statistics.median(v.fps for v in self.viewers) if self.viewers else 0.0

    @property
    def max_gap_s(self) -> float:
        return max((v.max_gap_s for v in self.viewers), default=float("inf"))

    @property
    def encodes_per_frame(self) -> float:
        return self.encodes / self.frames if self.frames else 0.0

    @property
    def delay_s(self) -> float:
        """The median viewer's median delay behind the race."""
        return median([v.delay_median_s for v in self.viewers])

    @property
    def delivered(self) -> int:
        """Frame messages the viewers got, all of them (late ones too)."""
        return sum(v.received for v in self.viewers)

    def cpu_per_frame(self) -> dict[str, float]:
        """CPU per frame, machine-independent units: ``race_ms`` a frame shown (the race's
        whole step: simulation, policies, picture, JPEG, MP4); ``daphne_us`` and
        ``viewers_us`` a frame delivered (one frame message to one viewer)."""
        cpu, got = self.cpu_s, self.delivered
        return {
            "race_ms": 1e3 * cpu.get("race", 0.0) / self.frames if self.frames else float("nan"),
            "daphne_us": 1e6 * cpu.get("daphne", 0.0) / got if got else float("nan"),
            "viewers_us": 1e6 * cpu.get("viewers", 0.0) / got if got else float("nan"),
        }


def live_result(arrivals: list[list[tuple[float, float | None]]], shown: list[tuple[float, float]],
                end: float, *, wanted: int, encodes: int, sent: int) -> Live:  # fmt: skip
    """What the viewers got: ``arrivals`` one list of ``(monotonic time, race clock)`` per
    connected viewer, ``shown`` the race's frames as ``(race clock, monotonic time)``; the
    window runs from :data:`SETTLE_S` after the first frame to ``end``."""
    start = (shown[0][1] if shown else end) + SETTLE_S
    shown_at = dict(shown)
    viewers = [viewer_window(times, start, end, shown_at) for times in arrivals]
    return Live(viewers=viewers, connected=len(arrivals), wanted=wanted, frames=len(shown),
                encodes=encodes, sent=sent, window_s=max(0.0, end - start),
                shown_s=shown[-1][1] - shown[0][1] if shown else 0.0)  # fmt: skip


@dataclass
class Race:
    """One race: its steps and clock, wall and CPU seconds, what the cars did; ``live`` for a
    broadcast one."""

    seed: int
    steps: int
    clock_s: float
    wall_s: float
    """From the call to :func:`run_race` to its return (the race's set-up included)."""
    stepping_s: float
    """From the end of the first step to the end of the last."""
    cpu_s: float
    cars: list[str]
    car_steps: int
    """Steps the cars drove (each asked its policy), all cars together."""
    live: Live | None = None

    @property
    def steps_per_s(self) -> float:
        """Steps per wall second while the race ran (its set-up left out)."""
        return (self.steps - 1) / self.stepping_s if self.stepping_s > 0 else 0.0

    @property
    def cpu_ms_per_step(self) -> float:
        return 1000.0 * self.cpu_s / self.steps if self.steps else 0.0


def median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def last_line(pairs: list[tuple[Race, Race]], spectators: int) -> str:
    """The key figures: medians over the seeds of (unpaced, live) pairs, worst gap of all."""
    lives = [live.live for _, live in pairs if live.live is not None]
    fps = median([r.fps for r in lives])
    paced = median([r.paced_fps for r in lives])
    gap = max((r.max_gap_s for r in lives), default=float("inf"))
    encodes = max((r.encodes_per_frame for r in lives), default=0.0)
    sim = median([base.steps_per_s for base, _ in pairs])
    ratio = median([live.cpu_ms_per_step / base.cpu_ms_per_step
                    for base, live in pairs if base.cpu_ms_per_step])  # fmt: skip
    connected = min((r.connected for r in lives), default=0)
    retried = max((r.retried for r in lives), default=0)
    frames = median([statistics.median(v.frames for v in r.viewers) for r in lives if r.viewers])
    delay = median([r.delay_s for r in lives])
    per = {key: median([r.cpu_per_frame()[key] for r in lives])
           for key in ("race_ms", "daphne_us", "viewers_us")}  # fmt: skip
    return (f"race_fps={fps:.2f} paced_fps={paced:.2f} max_gap_s={gap:.2f} "
            f"encodes_per_frame={encodes:.3f} sim_steps_per_s={sim:.1f} "
            f"realtime={fps / REALTIME_FPS:.3f} ratio={ratio:.2f} "
            f"delay_s={delay:.2f} frames_per_viewer={frames:.0f} "
            f"spectators={connected}/{spectators} retried={retried} "
            f"seeds={len(pairs)} race_cpu_ms_per_frame={per['race_ms']:.1f} "
            f"daphne_cpu_us_per_delivery={per['daphne_us']:.0f} "
            f"viewers_cpu_us_per_delivery={per['viewers_us']:.0f}")  # fmt: skip


# --------------------------------------------------------------------------- the viewers
def mask(payload: bytes) -> bytes:
    """A client frame's masking (RFC 6455 5.3): a random key, then the payload XORed with it."""
    key = os.urandom(4)
    return key + bytes(b ^ key[i % 4] for i, b in enumerate(payload))


def race_clock(payload: bytes) -> float | None:
    """The ``timing.clock_s`` of a frame message (its JSON header), or None."""
    from racing.framecodec import decode_header  # the one frame format

    try:
        return float(decode_header(payload)[0]["timing"]["clock_s"])
    except (ValueError, KeyError, TypeError):
        return None


def upgrade_request(url: str) -> tuple[str, int, bytes]:
    """Host, port and the websocket handshake request for ``url`` (with the Origin a browser
    sends)."""
    parts = urlsplit(url)
    host, port = parts.hostname or "127.0.0.1", parts.port or 80
    key = base64.b64encode(os.urandom(16)).decode()
    request = (f"GET {parts.path} HTTP/1.1\r\nHost: {host}:{port}\r\n"
               "Upgrade: websocket\r\nConnection: Upgrade\r\n"
               f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
               f"Origin: http://{host}:{port}\r\n\r\n")  # fmt: skip
    return host, port, request.encode()


class ViewerProtocol(asyncio.BufferedProtocol):
    """One viewer's connection: the handshake (:attr:`accepted`), then every message parsed
    where the socket put it, in one buffer the socket reads into (``recv_into``): a frame
    message's arrival time (when its last byte was read) and race clock (its header read with
    the one frame decoder, :func:`race_clock`) appended to ``times``; pongs for daphne's
    pings; :attr:`closed` once the connection ends. The picture itself is never copied."""

    BUFFER, MIN_READ = 1 << 20, 256 << 10

    def __init__(self, request: bytes, times: list[tuple[float, float | None]]) -> None:
        loop = asyncio.get_running_loop()
        self.request, self.times = request, times
        self.accepted, self.closed = loop.create_future(), loop.create_future()
        self.buffer = bytearray(self.BUFFER)
        self.view = memoryview(self.buffer)
        self.start = self.end = self.need = 0  # unparsed bytes: [start, end)
        self.fragments: list[bytes] = []
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport
        transport.write(self.request)

    def connection_lost(self, exc) -> None:
        if not self.accepted.done():
            self.accepted.set_exception(ConnectionError("closed during the handshake"))
        if not self.closed.done():
            self.closed.set_result(None)

    def get_buffer(self, sizehint: int) -> memoryview:
        if len(self.buffer) - self.end < self.MIN_READ:  # move what is left to a new buffer
            pending = self.end - self.start
            buffer = bytearray(max(self.BUFFER, 2 * max(pending, self.need)))
            buffer[:pending] = self.view[self.start : self.end]
            self.buffer, self.view = buffer, memoryview(buffer)
            self.start, self.end = 0, pending
        return self.view[self.end :]

    def buffer_updated(self, nbytes: int) -> None:
        self.end += nbytes
        if not self.accepted.done() and not self._handshake():
            return
        buffer, start = self.buffer, self.start
        while self.end - start >= 2:
            b0, b1 = buffer[start], buffer[start + 1]
            length, at = b1 & 0x7F, start + 2
            if length >= 126:
                size = 2 if length == 126 else 8
                if self.end < at + size:
                    break
                length, at = int.from_bytes(buffer[at : at + size], "big"), at + size
            if self.end < at + length:
                self.need = at + length - start
                break
            start, self.need = at + length, 0
            self._message(b0 & 0x0F, b0 & 0x80, self.view[at:start])
        self.start = start
        if start == self.end:
            self.start = self.end = 0

    def _handshake(self) -> bool:
        head = bytes(self.view[: self.end])
        if b"\r\n\r\n" not in head:
            return False
        status = head.split(b"\r\n", 1)[0]
        if b" 101 " not in status:
            self.accepted.set_exception(ConnectionError(status.decode(errors="replace")))
            self.transport.close()
            return False
        self.start = head.index(b"\r\n\r\n") + 4
        self.accepted.set_result(None)
        return True

    def _message(self, opcode: int, fin: int, payload: memoryview) -> None:
        if opcode == 0x8:  # close
            self.transport.close()
        elif opcode == 0x9:  # ping
            pong = bytes(payload)
            self.transport.write(bytes([0x8A, 0x80 | len(pong)]) + mask(pong))
        elif opcode in (0x2, 0x0):  # a frame: binary, maybe in fragments
            if not fin:
                self.fragments.append(bytes(payload))
                return
            if self.fragments:
                payload, self.fragments = b"".join([*self.fragments, payload]), []
            self.times.append((time.monotonic(), race_clock(payload)))


async def view(url: str, times: list[tuple[float, float | None]], opened: asyncio.Future) -> None:
    """One anonymous viewer (:class:`ViewerProtocol`): the handshake (tried
    :data:`CONNECT_TRIES` times, 1 s, 2 s, 4 s apart, as the page does), then every frame
    message until the connection ends. Sets ``opened`` once the handshake ended: the number of
    failed tries before it worked, or the last try's exception."""
    loop = asyncio.get_running_loop()
    host, port, request = upgrade_request(url)
    for tries in range(CONNECT_TRIES):
        transport = None
        try:
            transport, protocol = await loop.create_connection(
                lambda: ViewerProtocol(request, times), host, port)  # fmt: skip
            await protocol.accepted
            break
        except OSError as exc:  # ConnectionError included
            if transport is not None:
                transport.close()
            if tries == CONNECT_TRIES - 1:
                opened.set_result(exc)
                return
            await asyncio.sleep(2.0**tries)
    opened.set_result(tries)
    try:
        await protocol.closed
    finally:
        transport.close()


async def spectate(url: str, count: int, out: Path) -> None:
    """``count`` viewers of ``url``; prints ``READY <connected> <failed> <retried> <first
    error>`` once every handshake ended (``retried``: connected after a failed try), listens
    until SIGTERM and then until the frames stop (no frame for :data:`QUIET_S`), then writes
    the connected viewers' frames to ``out`` as JSON."""
    race_clock(b"")  # the frame decoder loaded before the race, as a browser has its page's
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    times: list[list[tuple[float, float | None]]] = [[] for _ in range(count)]
    opened = [loop.create_future() for _ in range(count)]
    tasks = []
    for i in range(count):  # a few at a time, as people arrive
        tasks.append(asyncio.create_task(view(url, times[i], opened[i])))
        if i % 10 == 9:
            await asyncio.sleep(0.05)
    done, _ = await asyncio.wait(opened, timeout=CONNECT_TIMEOUT_S)
    results = [f.result() if f in done else TimeoutError("no handshake") for f in opened]
    ok = [isinstance(r, int) for r in results]
    retried = sum(isinstance(r, int) and r > 0 for r in results)
    errors = [repr(r) for r in results if not isinstance(r, int)]
    print(f"{READY} {sum(ok)} {count - sum(ok)} {retried} {errors[0] if errors else ''}",
          flush=True)  # fmt: skip
    await stop.wait()
    stopped = time.monotonic()
    while time.monotonic() - stopped < MAX_DRAIN_S:
        last = max((t[-1][0] for t in times if t), default=0.0)
        if time.monotonic() - max(last, stopped) > QUIET_S:
            break
        await asyncio.sleep(0.1)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    out.write_text(json.dumps([t for t, good in zip(times, ok, strict=True) if good]))


# ------------------------------------------------------------------------------ the races
class CountedPolicy:
    """A policy that counts the observations it acted on."""

    def __init__(self, policy) -> None:
        self.policy, self.calls = policy, 0

    def __call__(self, obs):
        self.calls += 1
        return self.policy(obs)


def race_entries(seed: int, cars: int = 2) -> list:
    """The first ``cars`` of :data:`CARS`, with the console's default network and action
    space (their policies counted: :class:`CountedPolicy`)."""
    import inspect

    import torch

    from racing.actions import DEFAULT_DISCRETE
    from racing.headtohead import Racer
    from training.rl.checkpoints import new_model
    from training.rl.evaluation import sb3_policy
    from training.rl.metadata import build_metadata
    from training.rl.race import RaceEntry
    from training.services.models import model_create

    network = inspect.signature(model_create).parameters["neural_network"].default
    actions = [dict(a) for a in DEFAULT_DISCRETE]
    entries = []
    for index, sensors in enumerate(CARS[:cars]):
        torch.manual_seed(seed * 10 + index)  # the untrained weights, per seed
        metadata = build_metadata(action_space=actions, sensor=list(sensors),
                                  neural_network=network)  # fmt: skip
        name = f"Car {index + 1} ({' + '.join(sensors)})"
        policy = CountedPolicy(sb3_policy(new_model(metadata)))
        racer = Racer(sensors=sensors, action_space=actions, name=name)
        entries.append(RaceEntry(key=index, name=name, racer=racer, policy=policy))
    return entries


class StepLimit:
    """``should_stop`` for :func:`run_race`: true once it has been asked ``steps`` times (it is
    asked once a step, after the step); times the first and the last step's end."""

    def __init__(self, steps: int) -> None:
        self.steps, self.asked = steps, 0
        self.first = self.last = 0.0

    def __call__(self) -> bool:
        self.asked += 1
        self.last = time.monotonic()
        if self.asked == 1:
            self.first = self.last
        return self.asked >= self.steps

    @property
    def stepping_s(self) -> float:
        """Wall seconds from the end of the first step to the end of the last."""
        return self.last - self.first


class FrameClock:
    """Wraps an ``on_frame``: ``shown`` lists each frame's race clock (as the timing sends it)
    and the monotonic time it was handed on, once paced."""

    def __init__(self, on_frame) -> None:
        self.on_frame = on_frame
        self.shown: list[tuple[float, float]] = []

    def __call__(self, rgb, header: dict) -> None:
        self.on_frame(rgb, header)
        self.shown.append((header["timing"]["clock_s"], time.monotonic()))


def race_once(seed: int, args: argparse.Namespace, *, broadcast=None
              ) -> tuple[Race, FrameClock | None]:  # fmt: skip
    """One race of ``args.seconds`` of race clock; live with ``broadcast`` (a RaceBroadcast),
    whose frames are timed (the clock returned with the race, ``None`` unwatched)."""
    from racing.race import RaceConfig
    from racing.tracks import TrackCatalog
    from training.rl.race import RaceSettings, run_race

    track = TrackCatalog([]).load(args.track)
    config = RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=BOTS, bot_speed=BOT_SPEED_MPS)
    steps = max(1, round(args.seconds * REALTIME_FPS))
    limit_s = min(3600.0, max(10.0, args.seconds + 1))  # RaceSettings' range
    video = broadcast is not None and args.video
    settings = RaceSettings(
        laps=10,
        time_limit_s=limit_s,
        seed=seed,
        record_video=video,
        off_track_penalty_s=args.penalty_s,
        crash_penalty_s=args.penalty_s,
    )
    entries = race_entries(seed, args.cars)
    on_frame = FrameClock(broadcast.frame) if broadcast is not None else None
    cpu, wall = time.process_time(), time.monotonic()
    limit = StepLimit(steps)
    report = run_race(entries, track, settings, race=config, should_stop=limit,
                      on_frame=on_frame, title="bench_race")  # fmt: skip
    wall, cpu = time.monotonic() - wall, time.process_time() - cpu
    cars = [f"{c.status} {c.progress:.1f}% off {c.off_track} crash {c.crashes}"
            for c in sorted(report.cars, key=lambda c: str(c.key))]  # fmt: skip
    driven = sum(entry.policy.calls for entry in entries)
    race = Race(seed, report.steps, report.race_time_s, wall, limit.stepping_s, cpu, cars, driven)
    return race, on_frame


# ------------------------------------------------------------------------ the console
def proc_cpu_s(pid: int | None) -> float:
    """User + system CPU seconds of process ``pid`` so far (0 when it is gone); ``None``: of
    the whole machine, every core (``/proc/stat``: all but idle and iowait)."""
    tick = os.sysconf("SC_CLK_TCK")
    try:
        if pid is None:
            jiffies = [int(x) for x in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
            return (sum(jiffies[:8]) - jiffies[3] - jiffies[4]) / tick
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / tick


def console_env(var: Path, redis_url: str, prefix: str) -> dict[str, str]:
    """This process's and daphne's environment: the temporary database and folder, Redis."""
    env = {k: v for k, v in os.environ.items() if k not in ("DATABASE_URL", "REDIS_URL")}
    env.update({"RACECRAFT_VAR_DIR": str(var), "DATABASE_URL": f"sqlite:///{var / 'db.sqlite3'}",
                "REDIS_URL": redis_url, "REDIS_PREFIX": prefix, "DEBUG": "0",
                "SECRET_KEY": "bench-only-key", "ALLOWED_HOSTS": "127.0.0.1,localhost",
                "LOG_LEVEL": "WARNING", "SECURE_SSL_REDIRECT": "0", "SECURE_HSTS_SECONDS": "0",
                "DJANGO_SETTINGS_MODULE": "console.settings"})  # fmt: skip
    return env


def public_event(track_id: str) -> int:
    """A migrated database with a public head-to-bot event on ``track_id``, open now; its id."""
    from datetime import timedelta

    from django.contrib.auth import get_user_model
    from django.core.management import call_command
    from django.utils import timezone

    from leaderboard.models import Event

    call_command("migrate", verbosity=0)
    organiser = get_user_model().objects.create_user("organiser")
    now = timezone.now()
    event = Event.objects.create(
        organiser=organiser, name="Race day", track_id=track_id, race_type="HEAD_TO_BOT",
        bot_count=BOTS, bot_speed_mps=BOT_SPEED_MPS, opens_at=now - timedelta(hours=1),
        closes_at=now + timedelta(days=1), is_private=False,
    )  # fmt: skip
    return event.pk


def delete_prefixed(redis_url: str, prefix: str) -> None:
    import redis

    client = redis.Redis.from_url(redis_url)
    try:
        keys = list(client.scan_iter(match=f"{prefix}*", count=1000))
        if keys:
            client.delete(*keys)
    finally:
        client.close()


def run_live(seed: int, args: argparse.Namespace, url: str, group: str, pids: dict[str, int],
             env: dict[str, str], scratch: Path) -> Race:  # fmt: skip
    """The live race, watched by ``args.spectators`` viewers in a child process."""
    from training.worker.racelive import RaceBroadcast

    out = scratch / f"viewers-{seed}.json"
    viewers = subprocess.Popen(
        [sys.executable, __file__, "--spectate", url, "--spectators", str(args.spectators),
         "--out", str(out)],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        ready = viewers.stdout.readline().split(maxsplit=4) if viewers.stdout else []
        if not ready or ready[0] != READY:
            raise SystemExit(f"the viewers did not start ({viewers.poll()})")
        if int(ready[1]) == 0:
            raise SystemExit(f"no viewer could connect: {' '.join(ready[4:])}")
        failed = f"; {ready[2]} failed: {ready[4]}" if int(ready[2]) else ""
        print(f"seed {seed}: {ready[1]}/{args.spectators} viewers connected ({ready[3]} after "
              f"a failed try{failed})", flush=True)  # fmt: skip
        everyone = {**pids, "viewers": viewers.pid, "machine": None}
        before = {name: proc_cpu_s(pid) for name, pid in everyone.items()}
        broadcast = RaceBroadcast([group], paced=True)
        try:
            race, clock = race_once(seed, args, broadcast=broadcast)
            end = time.monotonic()
        finally:
            broadcast.close()
        cpu = {name: proc_cpu_s(pid) - before[name] for name, pid in everyone.items()}
        viewers.send_signal(signal.SIGTERM)
        viewers.wait(MAX_DRAIN_S + 30)
        arrivals = [[(t, c) for t, c in viewer] for viewer in json.loads(out.read_text())]
    finally:
        if viewers.poll() is None:
            viewers.kill()
            viewers.wait()
    sent = sum(p.sent for p in broadcast.publishers)
    race.live = live_result(arrivals, clock.shown, end, wanted=args.spectators, sent=sent,
                            encodes=broadcast.encodes)  # fmt: skip
    race.live.retried = int(ready[3])
    if broadcast.frames != race.live.frames:
        raise SystemExit(f"{broadcast.frames} frames paced but {race.live.frames} shown")
    race.live.cpu_s = {"race": race.cpu_s, **cpu}
    return race


def run_all(args: argparse.Namespace, var: Path, redis_url: str, env: dict[str, str]
            ) -> list[tuple[Race, Race]]:  # fmt: skip
    """daphne (and the embedded Redis) up, then per seed the unpaced race and the live one.
    ``env`` is already this process's environment: Django reads it at the first import."""
    import django
    from bench_load import free_port, wait_http  # the console's start, as the load bench does

    from console.launcher import ChildSpec, EmbeddedRedis, Supervisor, daphne_server_args

    pairs = []
    with Supervisor(stop_timeout=30) as sup:
        pids = {}
        if not args.redis_url:
            redis = EmbeddedRedis(var / "redis.sock", persist=False)
            if redis.url != redis_url:
                raise SystemExit(f"the embedded Redis is at {redis.url}, not {redis_url}")
            pids["redis"] = sup.start(redis.spec()).process.pid
            sup.wait_until(redis.ping, what="embedded Redis", timeout=30)
        django.setup()
        from django.conf import settings

        if not str(settings.DATABASES["default"]["NAME"]).startswith(str(var)):
            raise SystemExit("Django's settings were read before the bench set its database")
        from leaderboard.live import broadcast_group
        from training.rl.algorithms import set_torch_threads

        set_torch_threads(1)  # as the race worker: one observation per car and step
        event_id = public_event(args.track)
        port = free_port()
        argv = [sys.executable, "-m", "daphne", *daphne_server_args("127.0.0.1", port), "-v",
                "0", "console.asgi:application"]  # fmt: skip
        daphne = sup.start(ChildSpec("daphne", argv, env=env))
        pids["daphne"] = daphne.process.pid
        try:
            wait_http(port, daphne.process, timeout=START_TIMEOUT_S)
            url = f"ws://127.0.0.1:{port}/ws/league/events/{event_id}/broadcast/"
            for seed in range(args.seeds):
                base, _ = race_once(seed, args)
                print(f"seed {seed}: unpaced {base.steps} steps in {base.wall_s:.1f} s "
                      f"({base.steps_per_s:.0f} steps/s)", flush=True)  # fmt: skip
                live = run_live(seed, args, url, broadcast_group(event_id), pids, env, var)
                print(f"seed {seed}: live {live.steps} steps in {live.wall_s:.1f} s, median "
                      f"viewer {live.live.fps:.1f} fps", flush=True)  # fmt: skip
                pairs.append((base, live))
        finally:
            from django.db import connections

            connections.close_all()
            sup.stop_all()  # daphne first (reverse start order), then the embedded Redis
            if args.redis_url:
                delete_prefixed(args.redis_url, env["REDIS_PREFIX"])
    return pairs


# ------------------------------------------------------------------------------ the report
def report(pairs: list[tuple[Race, Race]], args: argparse.Namespace) -> None:
    video = "with the MP4" if args.video else "no MP4"
    cars = ", ".join(" + ".join(c) for c in CARS[: args.cars])
    print(f"\n{args.cars} cars ({cars}), {BOTS} bots at "
          f"{BOT_SPEED_MPS} m/s on {args.track}, {args.seconds:g} s of race clock, penalties "
          f"{args.penalty_s:g} s; live: paced at {REALTIME_FPS:.0f} fps, {video}, "
          f"{args.spectators} websocket viewers")  # fmt: skip
    print(f"{'seed':>4}{'run':>8}{'steps':>6}{'driven':>7}{'wall s':>7}{'steps/s':>8}"
          f"{'cpu ms/st':>10}{'shown':>6}{'enc':>5}{'sent':>5}{'viewers':>8}"
          f"{'win min/med/max':>16}{'got':>5}{'fps med':>8}{'fps min':>8}{'gap s':>6}"
          f"{'delay s':>8}{'max':>6}")  # fmt: skip
    for base, live in pairs:
        for run, race in (("unpaced", base), ("live", live)):
            row = (f"{race.seed:>4}{run:>8}{race.steps:>6}{race.car_steps:>7}"
                   f"{race.wall_s:>7.1f}{race.steps_per_s:>8.1f}"
                   f"{race.cpu_ms_per_step:>10.1f}")  # fmt: skip
            r = race.live
            if r is not None and r.viewers:
                got = [v.frames for v in r.viewers]
                spread = f"{min(got)}/{statistics.median(got):.0f}/{max(got)}"
                worst = max(v.delay_max_s for v in r.viewers)
                row += (f"{r.frames:>6}{r.encodes:>5}{r.sent:>5}"
                        f"{f'{r.connected}/{r.wanted}':>8}{spread:>16}"
                        f"{statistics.median(v.received for v in r.viewers):>5.0f}"
                        f"{r.fps:>8.2f}{min(v.fps for v in r.viewers):>8.2f}"
                        f"{r.max_gap_s:>6.2f}{r.delay_s:>8.2f}{worst:>6.2f}")  # fmt: skip
            print(row)
    print(
        "driven: car-steps that asked a policy; win: frames per viewer in the window "
        f"(from {SETTLE_S:g} s after the first frame to the race's end); got: all it got, "
        "late ones included; delay: from the race showing a frame to a viewer getting it"
    )
    same = all(base.cars == live.cars and base.steps == live.steps for base, live in pairs)
    print(f"\nthe same race unpaced and live (steps, each car's outcome): "
          f"{'yes' if same else 'NO'}")  # fmt: skip
    for _, live in pairs:
        for car in live.cars:
            print(f"  seed {live.seed}: {car}")
        if live.live is not None:
            r = live.live
            cpu = ", ".join(f"{name} {s:.1f} s ({100 * s / live.wall_s:.0f}%)"
                            for name, s in r.cpu_s.items())  # fmt: skip
            print(f"  seed {live.seed}: CPU during the live race ({live.wall_s:.1f} s wall; "
                  f"% of one core, the machine has {os.cpu_count()}): {cpu}")  # fmt: skip
            per = r.cpu_per_frame()
            print(
                f"  seed {live.seed}: CPU per frame: the race {per['race_ms']:.1f} ms a frame "
                f"shown; daphne {per['daphne_us']:.0f} us and the viewers "
                f"{per['viewers_us']:.0f} us a frame delivered ({r.delivered} delivered)"
            )
            print(f"  seed {live.seed}: the race showed {r.frames} frames in {r.shown_s:.1f} s "
                  f"({r.paced_fps:.2f} fps); window {r.window_s:.1f} s")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spectators", "--viewers", dest="spectators", type=int, default=100)
    parser.add_argument("--cars", type=int, default=2, choices=range(1, len(CARS) + 1))
    parser.add_argument("--seconds", type=float, default=30.0, help="race clock per race")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--track", default="racecraft_oval")
    parser.add_argument("--penalty-s", type=float, default=0.0,
                        help="off-track and crash penalty (DeepRacer's: 5)")  # fmt: skip
    parser.add_argument("--no-video", dest="video", action="store_false",
                        help="the live race records no MP4")  # fmt: skip
    parser.add_argument("--redis-url", default="", help="default: an embedded Redis")
    parser.add_argument("--spectate", help=argparse.SUPPRESS)  # a child: the viewers
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.spectate:
        asyncio.run(spectate(args.spectate, args.spectators, args.out))
        return
    var = Path(tempfile.mkdtemp(prefix="rc-bench-race-"))
    try:
        # Before any import of ours: importing ``console`` configures Django's settings.
        redis_url = args.redis_url or f"unix://{var / 'redis.sock'}?db=0"
        env = console_env(var, redis_url, f"bench-race-{secrets.token_hex(5)}:")
        os.environ.clear()
        os.environ.update(env)
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from bench_training import machine

        print(f"machine: {machine()}", flush=True)
        pairs = run_all(args, var, redis_url, env)
        print(f"machine after: {machine()}")
    finally:
        shutil.rmtree(var, ignore_errors=True)
    report(pairs, args)
    print(f"\n{last_line(pairs, args.spectators)}")


if __name__ == "__main__":
    main()
