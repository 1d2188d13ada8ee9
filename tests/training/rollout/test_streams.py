"""The Redis side of streamed training, through the tests' real Redis: tickets are taken once,
a dead worker's tickets go back (never a counted one), experience survives the trip checked."""

from __future__ import annotations

import uuid

import numpy as np
import pytest

from training.rollout.streams import (
    Session,
    StreamError,
    chunk_message,
    compress_obs,
    decompress_obs,
    read_chunk,
)

OBS = (120, 160, 1)


@pytest.fixture
def session(redis_url, settings):
    s = Session(redis_url, settings.REDIS_PREFIX, uuid.uuid4().hex)
    s.create()
    yield s
    s.cleanup()
    s.close()


def _chunk(steps: int = 3, **overrides) -> dict:
    rng = np.random.default_rng(0)
    fields = {
        "ticket": "0:1", "attempt": "a1", "worker": "w0", "version": 0, "seq": 0,
        "obs": rng.integers(0, 255, (steps, *OBS), dtype=np.uint8),
        "actions": np.arange(steps), "log_probs": np.full(steps, -1.0),
        "values": np.zeros(steps), "rewards": np.ones(steps),
        "infos": [{"status": "in_progress"}] * steps, "last": True, "terminated": True,
    }  # fmt: skip
    fields.update(overrides)
    return chunk_message(**fields)


def test_observations_compress_and_come_back_exactly():
    obs = np.random.default_rng(1).integers(0, 255, (5, *OBS), dtype=np.uint8)
    assert np.array_equal(decompress_obs(compress_obs(obs), obs.shape), obs)
    with pytest.raises(StreamError, match="wrong size"):
        decompress_obs(compress_obs(obs), (6, *OBS))  # a bomb or a lie: refused


def test_a_chunk_crosses_the_stream_and_is_checked(session):
    session.send(_chunk())
    [(entry_id, msg)] = list(session.read("trainer", block_ms=1000))
    chunk = read_chunk(msg, OBS, action_dim=0)
    assert chunk.steps == 3 and chunk.ticket == "0:1" and chunk.last and chunk.terminated
    assert chunk.obs.shape == (3, *OBS)
    session.ack(entry_id)
    assert session.r.xpending(session.keys.exp, "trainer")["pending"] == 0
    bad = _chunk()
    bad["rewards"] = np.ones(2, np.float32)  # one short
    with pytest.raises(StreamError, match="rewards"):
        read_chunk(bad, OBS, action_dim=0)
    nan = _chunk(values=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(StreamError, match="not finite"):
        read_chunk(nan, OBS, action_dim=0)


def test_tickets_are_taken_once_and_a_dead_workers_go_back(session):
    weights = {"w": np.ones(3, np.float32)}
    session.publish_policy(0, weights, episodes=3, evals=[{"start_progress": 50.0}])
    assert session.current_version() == 0
    assert np.array_equal(session.policy(0)["w"], weights["w"])
    assert session.claim("a", 0) == ("train", "0:0")
    assert session.claim("b", 0) == ("train", "0:1")
    assert session.claim("a", 0) == ("train", "0:2")
    assert session.claim("b", 0) == ("eval", "e:0:0:50.000")
    assert session.claim("a", 0) is None  # the quota is all taken
    session.done("a", "0:0")  # a's first episode was counted; a dies driving 0:2
    requeued, lost = session.requeue("a", counted={"0:0"}, version=0)
    assert requeued == 1 and lost == []
    assert session.claim("b", 0) == ("train", "0:2")  # another worker drives it
    requeued, lost = session.requeue("b", counted={"0:0", "0:1", "0:2"}, version=0)
    assert requeued == 0 and lost == ["e:0:0:50.000"]  # counted tickets never go back


def test_withdrawn_evaluation_laps_are_counted(session):
    session.publish_policy(1, {}, episodes=0, evals=[{"start_progress": 0.0}] * 3)
    assert session.claim("a", 1)[0] == "eval"
    assert session.withdraw(1) == 2
    assert session.claim("b", 1) is None


def test_a_stopping_worker_gives_back_its_unfinished_tickets(session):
    session.publish_policy(2, {}, episodes=2, evals=[{"start_progress": 0.0}])
    assert session.claim("zombie", 2) == ("train", "2:0")
    session.revoke("zombie")
    assert session.revoked("zombie") and not session.revoked("other")
    assert session.release("zombie") == 1
    assert [session.claim("other", 2) for _ in range(3)] == [
        ("train", "2:1"), ("train", "2:0"), ("eval", "e:2:0:0.000")
    ]  # fmt: skip
