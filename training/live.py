"""Live data for the console: metrics and video frames sent to a Channels group per job.

Frames are encoded by the rollout worker only while someone watches (a Redis key with a short
TTL that the websocket consumer keeps alive), at 15 fps at most, and handed to a background
thread that drops stale frames, so video never slows training. One frame is encoded once and
sent to the job's group once, however many viewers the group has; a publisher records how many
frames it got and sent (:func:`frame_counts`) when it closes.
"""

from __future__ import annotations

import asyncio
import base64
import logging
import queue
import threading
import time

import redis
from asgiref.sync import async_to_sync
from channels.layers import get_channel_layer
from django.conf import settings

log = logging.getLogger(__name__)
WATCH_TTL_S = 30
FRAME_COUNTS_TTL_S = 24 * 3600
"""How long a closed publisher's frame counts stay readable in Redis, seconds."""


def job_group(kind: str, job_id: int) -> str:
    """The Channels group of a job: ``training-<id>`` or ``evaluation-<id>``."""
    return f"{kind}-{job_id}"


def _watch_key(group: str) -> str:
    return f"{settings.REDIS_PREFIX or ''}racecraft:watching:{group}"


def _redis() -> redis.Redis:
    return redis.Redis.from_url(settings.REDIS_URL)


def mark_watching(group: str) -> None:
    """A viewer is on the page: workers send frames for the next ``WATCH_TTL_S`` seconds."""
    try:
        _redis().set(_watch_key(group), "1", ex=WATCH_TTL_S)
    except redis.RedisError:
        log.warning("could not mark %s as watched", group)


def _counts_key(group: str) -> str:
    return f"{settings.REDIS_PREFIX or ''}racecraft:frames:{group}"


def frame_counts(group: str) -> dict[str, int]:
    """``{"encoded", "sent"}``: the frames the last closed publisher of ``group`` got from the
    worker (each a JPEG pair, encoded once) and sent to the group (stale ones dropped); empty
    when none was recorded."""
    try:
        raw = _redis().hgetall(_counts_key(group))
    except redis.RedisError:
        return {}
    return {k.decode(): int(v) for k, v in raw.items()}


def is_watched(group: str) -> bool:
    try:
        return bool(_redis().exists(_watch_key(group)))
    except redis.RedisError:
        return False


def send(group: str, message: dict) -> bool:
    """Send one message to a group now (metrics, status changes); False when it could not."""
    layer = get_channel_layer()
    if layer is None:
        return False
    try:
        async_to_sync(layer.group_send)(group, message)
    except Exception:  # noqa: BLE001 - live updates are best effort; the job goes on
        log.warning("could not send a live update to %s", group, exc_info=True)
        return False
    return True


class _NewestSender:
    """What the frame senders share: a background thread fed through a two-slot queue that
    keeps only the newest item when the thread lags, and a once-a-second look at whether
    anyone watches ``group``. Subclasses send in ``_run`` until ``_stop`` is set."""

    def __init__(self, group: str, thread_name: str) -> None:
        self.group = group
        self._queue: queue.Queue = queue.Queue(maxsize=2)
        self._stop = threading.Event()
        self._watched = False
        self._checked = 0.0
        self.encoded = 0  # frames the worker encoded and handed over
        self.sent = 0  # frames sent (each once, for every viewer)
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        raise NotImplementedError

    def watched(self) -> bool:
        now = time.monotonic()
        if now - self._checked > 1.0:
            self._checked = now
            self._watched = is_watched(self.group)
        return self._watched

    def _put_newest(self, item: object) -> None:
        self.encoded += 1
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            try:
                self._queue.get_nowait()  # drop the stale frame
            except queue.Empty:
                pass
            try:
                self._queue.put_nowait(item)
            except queue.Full:
                pass

    def _join(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)


class FramePublisher(_NewestSender):
    """A background sender of video frames to a job's Channels group: keeps only the newest
    frame when it falls behind."""

    def __init__(self, group: str) -> None:
        super().__init__(group, f"frames-{group}")

    def publish(self, frame: dict) -> None:
        message = {
            "type": "job.frame",
            "camera": base64.b64encode(bytes(frame["camera"])).decode(),
            "chase": base64.b64encode(bytes(frame["chase"])).decode(),
            "progress": frame.get("progress"),
        }
        # What is happening (streamed training): "training" episode or "evaluation" lap, the
        # iteration and the policy version driving, for the page's overlay.
        for key in ("phase", "iteration", "version", "lap"):
            if frame.get(key) is not None:
                message[key] = frame[key]
        self._put_newest(message)

    def _run(self) -> None:
        # One event loop for the thread's life: async_to_sync for each frame would start a loop,
        # a thread and a Redis connection (the channel layer's pools are per loop) every time,
        # about 7 times the cost of a send on a busy machine - and frames dropped behind it.
        loop = asyncio.new_event_loop()
        try:
            while not self._stop.is_set():
                try:
                    message = self._queue.get(timeout=0.2)
                except queue.Empty:
                    continue
                self.sent += self._send(loop, message)
        finally:
            loop.close()  # channels_redis closes this loop's connections

    def _send(self, loop: asyncio.AbstractEventLoop, message: dict) -> bool:
        layer = get_channel_layer()
        if layer is None:
            return False
        try:
            loop.run_until_complete(layer.group_send(self.group, message))
        except Exception:  # noqa: BLE001 - live video is best effort; the job goes on
            log.warning("could not send a frame to %s", self.group, exc_info=True)
            return False
        return True

    def close(self) -> None:
        self._join()
        if not self.encoded:
            return
        try:
            r, key = _redis(), _counts_key(self.group)
            r.hset(key, mapping={"encoded": self.encoded, "sent": self.sent})
            r.expire(key, FRAME_COUNTS_TTL_S)
        except redis.RedisError:
            log.warning("could not record the frame counts of %s", self.group)


def broadcast_channel(group: str) -> str:
    """The Redis pub/sub channel of a broadcast's frames (:class:`BroadcastPublisher`)."""
    return f"{settings.REDIS_PREFIX or ''}racecraft:broadcast:{group}"


class BroadcastPublisher(_NewestSender):
    """Frames for a crowd: each frame PUBLISHed once to the group's Redis pub/sub channel
    (:func:`broadcast_channel`), where every web process holds one subscription and writes the
    frame to its own viewers (``leaderboard.broadcast.FrameHub``). Unlike a Channels group,
    which keeps a copy of every message for every viewer in Redis, a frame crosses Redis once
    per web process however many watch. The race never waits on Redis: a background thread
    sends, keeping only the newest frame when it lags."""

    def __init__(self, group: str) -> None:
        self.channel = broadcast_channel(group)
        super().__init__(group, f"broadcast-{group}")

    def offer(self, payload: bytes) -> None:
        self._put_newest(payload)

    def _run(self) -> None:
        client = _redis()
        while not self._stop.is_set():
            try:
                payload = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                client.publish(self.channel, payload)
                self.sent += 1
            except redis.RedisError:
                log.warning("could not publish a frame to %s", self.channel, exc_info=True)

    def close(self) -> None:
        self._join()
