"""The race-day broadcast: ``/ws/league/events/<event_id>/broadcast/[?watch=<token>]``.

Whoever can see the event joins its broadcast group, and so does anyone without an account
who brings the event's spectator token (an event setting; read-only: viewers only listen).
Anyone else is refused with close code 4404 before the handshake completes. Turning the
spectator link off (or replacing it) closes, at once, the open sockets it let in (close code
4403): the event's group gets an access message and each socket checks its access again (each
viewer's 10-second ping checks it too). Messages, as JSON:

- a binary message for each frame of the race on track, in the one frame format
  (:mod:`racing.framecodec`: a 4-byte big-endian length, that many bytes of JSON ``{"timing":
  {...}, "shot": {...}, "layout": {...}, "title": ..., "t": <unix time>}``, then the JPEG);
  built once by the race's worker at 15 frames/s (real time) however many watch, published
  once to Redis, and written untouched by each web process's :class:`FrameHub` to its viewers
  (under daphne framed once for all of them and handed to each socket: :class:`Wire`).
  The timing (:class:`racing.timing.Timing`) carries names, colours, times and positions only:
  spectators see the same frames. A process that cannot keep up skips frames, never falls
  behind: the hub reads Redis as fast as frames come and keeps only the newest frame not yet
  written; its writer sends that one as soon as it is done with the last. A slow machine shows
  fewer frames, never none (frames are not judged by their age in wall time: a loaded machine's
  frames, or a worker whose clock is behind, would all be "stale"). A frame that cannot be read
  is dropped. A viewer whose connection still holds unsent bytes of the last frame skips
  frames until it has taken it, then gets the newest;
- ``{"type": "status", ...}``: a race went on track (``started``, ``title``), or ended
  (``over``, with ``winner``, ``winner_time_s`` and ``standings``: names, positions and
  times), or the queue changed (``queue``, ``paused``). Spectators get only that
  (:func:`~leaderboard.live.spectator_status`); the event's organiser and facilitators also
  get the race id, its status and error and the raw results, model ids included.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import secrets
import time
from typing import Any
from urllib.parse import parse_qs

import redis.asyncio as aioredis
from asgiref.sync import sync_to_async
from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer
from django.conf import settings

from leaderboard.access import can_manage_event, can_view_event
from leaderboard.live import broadcast_group, spectator_status
from leaderboard.models import Event
from racing.framecodec import FrameError, decode_header
from training import live

log = logging.getLogger(__name__)
NOT_FOUND = 4404
REVOKED = 4403
"""The close code of a viewer whose access ended while watching (the link turned off)."""
LISTEN_POLL_S = 1.0
"""How often, at the longest, a process's listener checks that it still has viewers (s)."""
MARK_EVERY_S = 2.0
"""A process marks a group watched (a Redis write) at most this often: 500 viewers arriving
at once make one write, not 500 queued behind the access checks' database thread."""
_marked: dict[str, float] = {}


async def mark_watching(group: str) -> None:
    """:func:`training.live.mark_watching`, at most every :data:`MARK_EVERY_S` per process, off
    the database thread (it is a Redis write)."""
    now = time.monotonic()
    if now - _marked.get(group, float("-inf")) < MARK_EVERY_S:
        return
    _marked[group] = now
    await sync_to_async(live.mark_watching, thread_sensitive=False)(group)


def readable(payload: bytes) -> bool:
    """Whether ``payload`` is a frame in the one frame format (its header can be read)."""
    try:
        decode_header(payload)
    except FrameError:
        return False
    return True


class NewestFrame:
    """One channel's newest frame not yet written to its viewers: the reader replaces it (the
    one it replaces is skipped), the writer takes it when it is free."""

    def __init__(self) -> None:
        self.frame: bytes | None = None
        self.skipped = 0
        self._ready = asyncio.Event()

    def put(self, frame: bytes) -> None:
        if self.frame is not None:
            self.skipped += 1
        self.frame = frame
        self._ready.set()

    async def take(self, timeout: float) -> bytes | None:
        """The newest frame, once there is one; None after ``timeout`` seconds without."""
        try:
            await asyncio.wait_for(self._ready.wait(), timeout)
        except TimeoutError:
            return None
        self._ready.clear()
        frame, self.frame = self.frame, None
        return frame


class FrameHub:
    """A web process's one subscription per broadcast channel, fanned out to its viewers: a
    frame crosses Redis once per process, and each viewer costs only its websocket write.

    Two tasks per channel: the reader takes every frame off Redis as it comes (so Redis never
    queues frames for a slow process) into :attr:`newest`; the writer sends the newest one to
    every viewer, then the newest one again. However slow the writing, a viewer gets the
    newest frame next: a delayed process skips frames, never shows old ones, never none. The
    same holds per viewer (:meth:`fan_out`): a viewer whose connection has not taken the last
    frame yet is skipped, so a slow network holds at most one frame, never a queue."""

    viewers: dict[str, dict[AsyncJsonWebsocketConsumer, None]] = {}
    """Each channel's viewers in the order they joined (a frame goes out in that order)."""
    tasks: dict[str, asyncio.Task] = {}
    newest: dict[str, NewestFrame] = {}

    @classmethod
    def join(cls, channel: str, viewer: AsyncJsonWebsocketConsumer) -> None:
        cls.viewers.setdefault(channel, {})[viewer] = None
        task = cls.tasks.get(channel)
        loop = asyncio.get_running_loop()
        if task is None or task.done() or task.get_loop() is not loop:
            cls.tasks[channel] = loop.create_task(cls._listen(channel))

    @classmethod
    def leave(cls, channel: str, viewer: AsyncJsonWebsocketConsumer) -> None:
        viewers = cls.viewers.get(channel, {})
        viewers.pop(viewer, None)
        if not viewers:
            cls.viewers.pop(channel, None)
            task = cls.tasks.pop(channel, None)
            if task is not None and not task.done():
                task.cancel()

    @classmethod
    async def _listen(cls, channel: str) -> None:
        """Subscribe (again after a Redis outage, every second) and keep each readable frame
        as the channel's newest, with a writer task (:meth:`_write`) beside it, for as long as
        this task is the channel's. It looks at least every :data:`LISTEN_POLL_S`, so it ends
        once its viewers are gone even when a cancel is lost inside the Redis client (a
        listener left behind blocked the test loop's shutdown for 600 s on a loaded machine)."""
        me = asyncio.current_task()
        newest = cls.newest[channel] = NewestFrame()
        writer = asyncio.get_running_loop().create_task(cls._write(channel, newest, me))
        try:
            while cls.tasks.get(channel) is me:
                client = aioredis.Redis.from_url(settings.REDIS_URL)
                pubsub = client.pubsub()
                try:
                    await pubsub.subscribe(channel)
                    while cls.tasks.get(channel) is me:
                        message = await pubsub.get_message(ignore_subscribe_messages=True,
                                                           timeout=LISTEN_POLL_S)  # fmt: skip
                        if message is None or message.get("type") != "message":
                            continue
                        if readable(message["data"]):
                            newest.put(message["data"])
                except aioredis.RedisError:
                    log.warning("broadcast %s: Redis unavailable; subscribing again", channel)
                    await asyncio.sleep(1.0)
                finally:
                    try:
                        await pubsub.aclose()
                        await client.aclose()
                    except aioredis.RedisError:
                        pass
        finally:
            writer.cancel()
            if cls.newest.get(channel) is newest:
                del cls.newest[channel]

    @classmethod
    async def _write(cls, channel: str, newest: NewestFrame, owner: asyncio.Task) -> None:
        """Write the channel's newest frame to each of its viewers, then the newest one again,
        for as long as ``owner`` (its reader) is the channel's."""
        while cls.tasks.get(channel) is owner:
            frame = await newest.take(LISTEN_POLL_S)
            if frame is not None:
                await cls.fan_out(channel, frame)

    @classmethod
    async def fan_out(cls, channel: str, frame: bytes) -> None:
        """One frame to the channel's viewers as they are now. A viewer on daphne's websocket
        (:func:`wire_of`) gets the frame framed once for all of them
        (:meth:`Wire.write`), or, while its connection still holds unsent bytes of an earlier
        frame, nothing: it gets the newest frame once it has taken the last one (a slow
        viewer skips frames, never queues them, and never holds the others up). Any other
        viewer gets it through its consumer (``send``). A viewer that left (its access
        revoked) while the frame went out gets nothing after it left."""
        viewers = cls.viewers.get(channel)
        if not viewers:
            return
        prepared = None
        for viewer in list(viewers):
            if viewer not in viewers:
                continue  # left while an earlier viewer's send awaited
            wire = wire_of(viewer)
            try:
                if wire is None:
                    await viewer.send(bytes_data=frame)
                elif wire.backed_up():
                    viewer.frames_skipped = getattr(viewer, "frames_skipped", 0) + 1
                else:
                    if prepared is None:
                        prepared = wire.prepare(frame)
                    wire.write(prepared)
            except Exception:  # noqa: BLE001 - one viewer gone: the others go on
                log.debug("could not send a frame to a viewer", exc_info=True)


class Wire:
    """A viewer's websocket as daphne holds it (an autobahn ``WebSocketServerProtocol`` on a
    Twisted transport), for the frames only. The same frame goes to hundreds of viewers, so it
    is framed once (autobahn's ``prepareMessage``), and a viewer costs one ``send`` on its
    socket: on a plain TCP connection with nothing unsent the frame goes to the socket at once
    (what Twisted's buffered ``write`` would do a loop turn later, after registering the
    socket for writing and before unregistering it: two ``epoll_ctl`` calls and their Python a
    viewer a frame); whatever the socket does not take goes to Twisted's buffer, in order.
    Otherwise (TLS) autobahn's ``sendPreparedMessage``. Either way none of the ASGI path
    (consumer, session middleware, daphne's reply, autobahn framing a copy per viewer): most
    of what 7,500 frame messages a second (500 viewers) cost daphne. Status messages and
    closes still go through the consumer."""

    def __init__(self, protocol) -> None:
        self.protocol = protocol
        try:
            from twisted.internet.tcp import Connection
        except ImportError:  # pragma: no cover - daphne brings Twisted
            Connection = ()  # noqa: N806
        self.direct = isinstance(protocol.transport, Connection)

    def is_open(self) -> bool:
        protocol = self.protocol
        transport = protocol.transport
        if protocol.state != protocol.STATE_OPEN or transport is None:
            return False
        if getattr(transport, "disconnecting", False):
            return False
        connection = getattr(protocol.server, "connections", {}).get(protocol)
        return connection is not None and not connection.get("disconnected")

    def unsent(self) -> int:
        """Bytes written to this viewer that its socket has not taken yet (Twisted's buffer
        and autobahn's queue)."""
        protocol = self.protocol
        transport = protocol.transport
        try:
            held = len(transport.dataBuffer) - transport.offset + transport._tempDataLen
        except (AttributeError, TypeError):
            held = 0  # another transport (TLS): never skipped
        return held + len(protocol.send_queue)

    def backed_up(self) -> bool:
        """Whether a frame now would queue behind unsent bytes (or the socket closed)."""
        return not self.is_open() or self.unsent() > 0

    def prepare(self, frame: bytes):
        return self.protocol.factory.prepareMessage(frame, isBinary=True, doNotCompress=True)

    def write(self, prepared) -> None:
        """The prepared frame to this viewer; call only when not :meth:`backed_up`."""
        protocol = self.protocol
        if not self.direct:
            protocol.sendPreparedMessage(prepared)
            return
        data: bytes = prepared.payloadHybi
        transport = protocol.transport
        try:
            sent = transport.socket.send(data)
        except OSError:  # full (EAGAIN), or gone: Twisted's write finds out and closes
            sent = 0
        if sent < len(data):
            transport.write(data[sent:] if sent else data)


_WIRE_NEEDS = ("sendPreparedMessage", "factory", "transport", "send_queue", "server", "state")


def wire_of(viewer) -> Wire | None:
    """The daphne websocket under a Channels consumer, found through its ASGI ``send`` (daphne
    passes ``partial(server.handle_reply, protocol)``; Channels' session middleware wraps it,
    keeping daphne's as ``real_send``); cached on the viewer. ``None`` under another server
    (or in tests that fake one): the consumer's own ``send`` then."""
    try:
        return viewer.__dict__["_frame_wire"]
    except (KeyError, AttributeError):
        pass
    wire = None
    send = getattr(viewer, "base_send", None)
    for _ in range(8):  # a few middlewares deep at most
        if isinstance(send, functools.partial):
            protocol = send.args[0] if send.args else None
            if all(hasattr(protocol, name) for name in _WIRE_NEEDS):
                wire = Wire(protocol)
            break
        send = getattr(getattr(send, "__self__", None), "real_send", None)
        if send is None:
            break
    try:
        viewer.__dict__["_frame_wire"] = wire
    except AttributeError:
        pass
    return wire


def may_watch(user, event: Event, token: str) -> bool:
    """The event's viewers, and anyone with its spectator token while the link is on."""
    if event.spectator_token and token and secrets.compare_digest(token, event.spectator_token):
        return True
    return user is not None and can_view_event(user, event)


class BroadcastConsumer(AsyncJsonWebsocketConsumer):
    group = ""
    detail = False
    """Whether this viewer runs the event (organiser, facilitator): status messages whole."""

    @database_sync_to_async
    def watched_event(self) -> tuple[Event, bool] | None:
        """The URL's event, and whether this viewer runs it, when they may watch; else None
        (the only check, made on connect and again whenever the event's access changes)."""
        query = parse_qs(self.scope.get("query_string", b"").decode())
        token = (query.get("watch") or [""])[0]
        user = self.scope.get("user")
        try:
            event = Event.objects.get(pk=int(self.scope["url_route"]["kwargs"]["event_id"]))
        except (KeyError, ValueError, Event.DoesNotExist):
            return None
        if not may_watch(user, event, token):
            return None
        return event, user is not None and can_manage_event(user, event)

    async def connect(self) -> None:
        found = await self.watched_event()
        if found is None:
            await self.close(code=NOT_FOUND)
            return
        event, self.detail = found
        self.group = broadcast_group(event.pk)
        await self.channel_layer.group_add(self.group, self.channel_name)
        await self.accept()
        FrameHub.join(live.broadcast_channel(self.group), self)
        await mark_watching(self.group)

    async def _leave(self) -> None:
        if self.group:
            group, self.group = self.group, ""
            FrameHub.leave(live.broadcast_channel(group), self)
            await self.channel_layer.group_discard(group, self.channel_name)

    async def disconnect(self, code: int) -> None:
        await self._leave()

    async def _still_allowed(self) -> bool:
        """Check again; a viewer who lost access (the spectator link turned off or replaced,
        a racer removed from a private event) stops receiving anything and is closed."""
        found = await self.watched_event()
        if found is not None:
            self.detail = found[1]
            return True
        await self._leave()  # before the close: no frame or message slips out after it
        await self.close(code=REVOKED)
        return False

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        """Viewers only listen; a ping (every 10 s) keeps the worker sending frames, and checks
        the viewer's access again (the safety net of a lost access message)."""
        if self.group and await self._still_allowed():
            await mark_watching(self.group)

    async def raceday_access(self, message: dict) -> None:
        """The event's access changed (:func:`leaderboard.live.broadcast_access_changed`)."""
        if self.group:
            await self._still_allowed()

    async def raceday_status(self, message: dict) -> None:
        if not self.group:
            return
        if self.detail:
            await self.send_json({**{k: v for k, v in message.items() if k != "type"},
                                  "type": "status"})  # fmt: skip
        else:
            await self.send_json(spectator_status(message))
