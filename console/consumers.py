"""Websockets of a job's page: the live chart, video frames, status and lap progress.

``/ws/training/<id>/`` and ``/ws/evaluation/<id>/``. A consumer accepts only the owner of the
job (one helper, :meth:`JobConsumer.owned_job`; anyone else, signed in or not, is refused with
close code 4404 before the handshake completes), joins the job's group, keeps the job marked
as watched (workers encode frames only while someone watches) and relays the workers'
messages as JSON:

- ``{"type": "snapshot", "status", ...}`` first: the chart so far (training) or the laps
  done (evaluation), so that a viewer who joins late misses nothing;
- ``{"type": "metrics", "point"}``, one reward-graph point per iteration;
- ``{"type": "frame", "camera", "chase"}``, base64 JPEGs, and when the worker says so
  ``phase`` ("training" or "evaluation"), ``iteration``, ``version`` (the policy's) and ``lap``;
- ``{"type": "status", "status"[, "results"]}`` and ``{"type": "progress", "laps_done"}``.
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

from asgiref.sync import sync_to_async
from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer

from training import live, selectors
from training.models import EvaluationJob, TrainingJob

NOT_FOUND = 4404
"""Close code for a job that is not the user's (or does not exist): like an HTTP 404."""

WATCH_EVERY_S = 10.0
"""How often a connected viewer renews the watch mark (its TTL is live.WATCH_TTL_S)."""
FRAME_CONTEXT = ("phase", "iteration", "version", "lap")
"""What a worker may say about a frame (:class:`training.live.FramePublisher`)."""


class JobConsumer(AsyncJsonWebsocketConsumer):
    kind = ""  # "training" or "evaluation"

    group = ""
    _watcher: asyncio.Task | None = None

    @database_sync_to_async
    def owned_job(self) -> TrainingJob | EvaluationJob | None:
        """The job of the URL when the signed-in user owns it, else None (the only check)."""
        user = self.scope.get("user")
        if user is None or not user.is_authenticated:
            return None
        try:
            job_id = int(self.scope["url_route"]["kwargs"]["job_id"])
            return selectors.job_for_owner(user, self.kind, job_id)
        except (KeyError, ValueError, TrainingJob.DoesNotExist, EvaluationJob.DoesNotExist):
            return None

    async def connect(self) -> None:
        job = await self.owned_job()
        if job is None:
            await self.close(code=NOT_FOUND)
            return
        self.group = live.job_group(self.kind, job.pk)
        await self.channel_layer.group_add(self.group, self.channel_name)
        await self.accept()
        await sync_to_async(live.mark_watching)(self.group)
        self._watcher = asyncio.create_task(self._keep_watching())
        await self.send_json(await self.snapshot(job))

    async def disconnect(self, code: int) -> None:
        if self._watcher is not None:
            self._watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watcher
        if self.group:
            await self.channel_layer.group_discard(self.group, self.channel_name)

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        """Viewers only listen; anything they send is ignored."""

    async def _keep_watching(self) -> None:
        while True:
            await asyncio.sleep(WATCH_EVERY_S)
            await sync_to_async(live.mark_watching)(self.group)

    async def snapshot(self, job: TrainingJob | EvaluationJob) -> dict:
        raise NotImplementedError

    # ---- messages from workers (channel-layer types job.metrics, job.frame, ...)
    async def job_metrics(self, event: dict) -> None:
        await self.send_json({"type": "metrics", "point": event.get("point")})

    async def job_frame(self, event: dict) -> None:
        message = {"type": "frame", "camera": event.get("camera"), "chase": event.get("chase")}
        # What the frame shows (streamed training), for the page's caption over the video.
        for key in FRAME_CONTEXT:
            if isinstance(event.get(key), str | int):
                message[key] = event[key]
        await self.send_json(message)

    async def job_status(self, event: dict) -> None:
        message = {"type": "status", "status": event.get("status")}
        if "results" in event:
            message["results"] = event["results"]
        await self.send_json(message)

    async def job_progress(self, event: dict) -> None:
        await self.send_json({"type": "progress", "laps_done": event.get("laps_done")})


class TrainingConsumer(JobConsumer):
    kind = "training"

    @database_sync_to_async
    def snapshot(self, job: TrainingJob) -> dict:
        job.refresh_from_db()
        return {
            "type": "snapshot",
            "status": job.status,
            "points": selectors.chart_points(job),
            "elapsed_s": round(job.elapsed_seconds, 1),
            "remaining_s": round(job.remaining_seconds, 1),
            "max_minutes": job.max_minutes,
        }


class EvaluationConsumer(JobConsumer):
    kind = "evaluation"

    @database_sync_to_async
    def snapshot(self, job: EvaluationJob) -> dict:
        job.refresh_from_db()
        return {
            "type": "snapshot",
            "status": job.status,
            "laps_done": job.laps_done,
            "laps": job.laps,
        }
