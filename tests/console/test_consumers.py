"""The job websockets through the real ASGI app (auth, origin check, routing) and the real
channel layer on the tests' Redis: the owner gets the chart so far and every relayed message;
anyone else is refused with 4404."""

from __future__ import annotations

import pytest
from asgiref.sync import async_to_sync, sync_to_async
from channels.testing import WebsocketCommunicator
from django.conf import settings
from django.test import Client

from training import live
from training.models import EvaluationJob, IterationMetric, JobStatus, TrainingJob

pytestmark = pytest.mark.django_db(transaction=True)


def app_and_headers(client: Client | None) -> tuple[object, list[tuple[bytes, bytes]]]:
    from console.asgi import application

    # Whichever hosts the origin validator was built with (DEBUG defaults or the test hosts).
    validator = application.application_mapping["websocket"]
    origin = next((o for o in validator.allowed_origins if "*" not in o), "localhost")
    headers = [(b"origin", f"http://{origin}".encode()), (b"host", origin.encode())]
    if client is not None:
        session = client.cookies[settings.SESSION_COOKIE_NAME].value
        headers.append((b"cookie", f"{settings.SESSION_COOKIE_NAME}={session}".encode()))
    return application, headers


async def connect(client: Client | None, path: str) -> tuple[WebsocketCommunicator, bool, int]:
    app, headers = app_and_headers(client)
    communicator = WebsocketCommunicator(app, path, headers=headers)
    connected, code = await communicator.connect(timeout=10)
    return communicator, connected, code


@pytest.fixture
def training_job(alice_model) -> TrainingJob:
    job = TrainingJob.objects.create(model=alice_model, max_minutes=5,
                                     status=JobStatus.IN_PROGRESS)  # fmt: skip
    for n in (1, 2):
        IterationMetric.objects.create(
            job=job, iteration=n, episodes=4, steps=100, total_steps=100 * n,
            train_reward=10.0 * n, train_progress=5.0 * n, eval_progress=7.0 * n,
            is_best=n == 2, elapsed_s=30.0 * n,
        )  # fmt: skip
    return job


def test_the_owner_gets_the_chart_so_far_then_live_messages(training_job, alice_client) -> None:
    group = live.job_group("training", training_job.pk)

    async def scenario() -> None:
        ws, connected, _ = await connect(alice_client, f"/ws/training/{training_job.pk}/")
        assert connected
        snapshot = await ws.receive_json_from(timeout=10)
        assert snapshot["type"] == "snapshot" and snapshot["status"] == "IN_PROGRESS"
        assert [p["iteration"] for p in snapshot["points"]] == [1, 2]
        assert snapshot["points"][1]["is_best"] is True and snapshot["max_minutes"] == 5
        assert await sync_to_async(live.is_watched)(group)  # workers now send frames

        point = {
            "iteration": 3,
            "train_reward": 31.0,
            "train_progress": 16.0,
            "eval_progress": 22.0,
            "is_best": True,
            "elapsed_s": 90.0,
            "total_steps": 300,
        }
        await sync_to_async(live.send)(group, {"type": "job.metrics", "point": point})
        assert await ws.receive_json_from(timeout=10) == {"type": "metrics", "point": point}

        frame = {"type": "job.frame", "camera": "Y2FtZXJh", "chase": "Y2hhc2U=", "progress": 4}
        await sync_to_async(live.send)(group, frame)
        got = await ws.receive_json_from(timeout=10)
        assert got == {"type": "frame", "camera": "Y2FtZXJh", "chase": "Y2hhc2U="}
        # A streamed worker says what the frame shows; the page captions the video with it.
        frame.update(phase="evaluation", iteration=7, version=6, lap=2, secret={"x": 1})
        await sync_to_async(live.send)(group, frame)
        got = await ws.receive_json_from(timeout=10)
        assert got == {"type": "frame", "camera": "Y2FtZXJh", "chase": "Y2hhc2U=",
                       "phase": "evaluation", "iteration": 7, "version": 6, "lap": 2}  # fmt: skip

        await sync_to_async(live.send)(group, {"type": "job.status", "status": "STOPPING"})
        assert await ws.receive_json_from(timeout=10) == {"type": "status", "status": "STOPPING"}
        await ws.disconnect()

    async_to_sync(scenario)()


def test_a_quiet_socket_stays_open(training_job, alice_client) -> None:
    """Nothing to relay for longer than Redis's read timeout must not kill the consumer."""

    async def scenario() -> None:
        ws, connected, _ = await connect(alice_client, f"/ws/training/{training_job.pk}/")
        assert connected
        await ws.receive_json_from(timeout=10)
        assert await ws.receive_nothing(timeout=7)
        group = live.job_group("training", training_job.pk)
        await sync_to_async(live.send)(group, {"type": "job.progress", "laps_done": 1})
        assert await ws.receive_json_from(timeout=10) == {"type": "progress", "laps_done": 1}
        await ws.disconnect()

    async_to_sync(scenario)()


def test_evaluation_socket_relays_progress_and_results(alice_model, alice_client) -> None:
    evaluation = EvaluationJob.objects.create(
        model=alice_model, track_id="racecraft_oval", status=JobStatus.IN_PROGRESS, laps_done=1
    )
    group = live.job_group("evaluation", evaluation.pk)

    async def scenario() -> None:
        ws, connected, _ = await connect(alice_client, f"/ws/evaluation/{evaluation.pk}/")
        assert connected
        assert await ws.receive_json_from(timeout=10) == {
            "type": "snapshot", "status": "IN_PROGRESS", "laps_done": 1, "laps": 3,
        }  # fmt: skip
        await sync_to_async(live.send)(group, {"type": "job.progress", "laps_done": 2})
        assert await ws.receive_json_from(timeout=10) == {"type": "progress", "laps_done": 2}
        done = {"type": "job.status", "status": "COMPLETED", "results": {"laps": []}}
        await sync_to_async(live.send)(group, done)
        assert await ws.receive_json_from(timeout=10) == {
            "type": "status", "status": "COMPLETED", "results": {"laps": []},
        }  # fmt: skip
        await ws.disconnect()

    async_to_sync(scenario)()


def test_others_and_strangers_are_refused(training_job, charlie_client) -> None:
    evaluation = EvaluationJob.objects.create(model=training_job.model, track_id="racecraft_oval")

    async def scenario() -> None:
        for client, path in (
            (charlie_client, f"/ws/training/{training_job.pk}/"),
            (charlie_client, f"/ws/evaluation/{evaluation.pk}/"),
            (None, f"/ws/training/{training_job.pk}/"),
            (charlie_client, "/ws/training/999999/"),
        ):
            ws, connected, code = await connect(client, path)
            assert not connected and code == 4404, path
            await ws.wait()

    async_to_sync(scenario)()
    assert not live.is_watched(live.job_group("training", training_job.pk))


def test_twenty_viewers_of_one_job_cost_one_encode_per_frame(
    training_job, alice_client, monkeypatch
) -> None:
    """Issue 14: the worker encodes a frame once (two JPEGs: camera and chase view) and sends
    it to the job's group once; every viewer gets every frame, however many watch."""
    import asyncio
    import base64

    from tests.console.conftest import ACTIONS
    from training.rollout import envs

    viewers, frames = 20, 3
    encodes: list[str] = []
    real_imencode = envs.cv2.imencode

    def imencode(ext, image, params):
        encodes.append(ext)
        return real_imencode(ext, image, params)

    monkeypatch.setattr(envs.cv2, "imencode", imencode)
    env = envs.EnvSpec(track="racecraft_oval", action_space=ACTIONS).make()
    grabber = envs.FrameGrabber(env, interval_s=0.0)
    group = live.job_group("training", training_job.pk)
    path = f"/ws/training/{training_job.pk}/"

    async def scenario() -> tuple[list[dict], list[list[dict]], live.FramePublisher]:
        sockets = [(await connect(alice_client, path))[0] for _ in range(viewers)]
        for ws in sockets:
            assert (await ws.receive_json_from(timeout=10))["type"] == "snapshot"
        publisher = live.FramePublisher(group)  # the worker's frame sender
        sent, got = [], [[] for _ in sockets]
        obs, _ = env.reset(seed=1)
        for _ in range(frames):
            obs = env.step(1)[0]
            frame = grabber.grab(obs)
            sent.append(frame)
            publisher.publish(frame)
            # One at a time: the publisher keeps only the newest frame when it falls behind.
            for ws, mine in zip(sockets, got, strict=True):
                mine.append(await ws.receive_json_from(timeout=10))
        quiet = await asyncio.gather(*(ws.receive_nothing(timeout=0.3) for ws in sockets))
        assert all(quiet), "a viewer got a frame twice"
        await sync_to_async(publisher.close)()
        await asyncio.gather(*(ws.disconnect() for ws in sockets))
        return sent, got, publisher

    try:
        sent, got, publisher = async_to_sync(scenario)()
    finally:
        env.close()
    assert len(encodes) == 2 * frames  # camera + chase per frame, not per viewer
    assert publisher.encoded == publisher.sent == frames
    assert live.frame_counts(group) == {"encoded": frames, "sent": frames}
    expected = [base64.b64encode(f["camera"].tobytes()).decode() for f in sent]
    for mine in got:
        assert [m["type"] for m in mine] == ["frame"] * frames
        assert [m["camera"] for m in mine] == expected
