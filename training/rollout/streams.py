"""The Redis side of streamed training: simulation workers that own their episodes.

The trainer and its simulation workers share one *session* in Redis (all keys under
``<prefix>racecraft:sim:<session>:``):

- ``version`` and ``policy:<v>``: the trainer publishes each policy version's weights (a
  :mod:`training.sandbox.protocol` frame of plain arrays: nothing is unpickled); a worker picks
  up a new version between episodes.
- ``tickets:<v>`` and ``evals:<v>``: the episode quota of a version, one ticket per training
  episode (``num_episodes_between_training`` of them) and per evaluation lap. A worker takes a
  ticket with an atomic ``LMOVE`` into its own ``claimed:<worker>`` list, so the split across
  workers is DeepRacer's "whoever is free drives the next one": a fast worker drives more. When a
  worker's ``alive:<worker>`` heartbeat expires, the trainer moves its claimed tickets back, and
  another worker drives them. The trainer counts a ticket once, on its episode's last chunk; a
  late or repeated copy of a counted ticket is dropped.
- ``exp``: a Redis stream (``XADD`` with an approximate ``MAXLEN``, read with ``XREADGROUP`` by
  the trainer's consumer group, ``XACK`` once taken in) of experience chunks (up to
  ``CHUNK_STEPS`` steps of one episode: zlib-compressed observations, actions, log-probabilities,
  values, rewards, the compact infos, and on the last chunk how the episode ended with the value
  to bootstrap from), evaluation results and worker errors.
- ``frames``: a short stream of live video frames from the one worker named in ``watch``.
- ``stop``: the trainer is done; workers end.

This module is transport only (no torch, no policy): the workers themselves are
:mod:`training.rl.simulation`, the trainer's side is :mod:`training.rollout.streamed`.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import redis

from training.sandbox import checked
from training.sandbox.protocol import ProtocolError, decode, encode

CHUNK_STEPS = 64
"""Steps of one episode per experience message."""
EXP_MAXLEN = 20_000
"""Bound of the experience stream (messages; the trainer reads far faster than it grows)."""
FRAMES_MAXLEN = 16
ALIVE_TTL_S = 15.0
"""A worker whose heartbeat is older than this is dead: its claimed tickets go back. Generous:
a loaded machine may not schedule a worker for seconds, and a local worker's death is seen at
once anyway (its process exits)."""
HEARTBEAT_S = 1.0
KEY_TTL_S = 3600
GROUP = "trainer"
MAX_MESSAGE_BYTES = 256 << 20


class StreamError(RuntimeError):
    """Malformed data on a session's streams."""


def client(redis_url: str) -> redis.Redis:
    """A client whose socket outlasts the blocking reads used here (a few seconds)."""
    return redis.Redis.from_url(redis_url, socket_timeout=60, socket_connect_timeout=10)


@dataclass(frozen=True)
class Keys:
    """The Redis keys of one session."""

    prefix: str
    session: str

    @property
    def base(self) -> str:
        return f"{self.prefix}racecraft:sim:{self.session}:"

    def __getattr__(self, name: str) -> str:
        if name.startswith("_"):
            raise AttributeError(name)
        return self.base + name

    def policy(self, version: int) -> str:
        return f"{self.base}policy:{version}"

    def tickets(self, version: int) -> str:
        return f"{self.base}tickets:{version}"

    def evals(self, version: int) -> str:
        return f"{self.base}evals:{version}"

    def claimed(self, worker: str) -> str:
        return f"{self.base}claimed:{worker}"

    def alive(self, worker: str) -> str:
        return f"{self.base}alive:{worker}"

    def revoked(self, worker: str) -> str:
        return f"{self.base}revoked:{worker}"


# ------------------------------------------------------------------------------- messages
def pack(message: dict) -> bytes:
    return encode(message)[4:]


def unpack(body: bytes) -> dict:
    """A message from a stream, as a dict (arrays as numpy arrays), or :class:`StreamError`."""
    if len(body) > MAX_MESSAGE_BYTES:
        raise StreamError("a stream message is too large")
    try:
        value = decode(body)
    except ProtocolError as exc:
        raise StreamError(f"a malformed stream message ({exc})") from None
    if not isinstance(value, dict) or not isinstance(value.get("kind"), str):
        raise StreamError("a stream message without a kind")
    return value


def compress_obs(obs: np.ndarray) -> np.ndarray:
    """Camera frames compress about 4x with zlib's fastest level, at ~0.1 ms a frame."""
    data = zlib.compress(np.ascontiguousarray(obs, dtype=np.uint8).tobytes(), 1)
    return np.frombuffer(data, dtype=np.uint8)


def decompress_obs(data: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``shape`` = (steps, *obs shape); the size is checked before and after inflating."""
    if not isinstance(data, np.ndarray) or data.dtype != np.uint8 or data.ndim != 1:
        raise StreamError("observations: expected compressed bytes")
    expected = int(np.prod(shape))
    try:
        raw = zlib.decompressobj().decompress(data.tobytes(), expected + 1)
    except zlib.error as exc:
        raise StreamError(f"observations do not inflate ({exc})") from None
    if len(raw) != expected:
        raise StreamError("observations: wrong size")
    return np.frombuffer(raw, dtype=np.uint8).reshape(shape)


@dataclass
class Chunk:
    """Up to ``CHUNK_STEPS`` steps of one training episode (checked on arrival)."""

    ticket: str
    attempt: str
    worker: str
    version: int
    seq: int
    obs: np.ndarray
    actions: np.ndarray
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    infos: list[dict]
    last: bool
    terminated: bool
    bootstrap: float

    @property
    def steps(self) -> int:
        return len(self.rewards)


def chunk_message(*, ticket: str, attempt: str, worker: str, version: int, seq: int,
                  obs: np.ndarray, actions: np.ndarray, log_probs: np.ndarray,
                  values: np.ndarray, rewards: np.ndarray, infos: list[dict], last: bool,
                  terminated: bool = False, bootstrap: float = 0.0) -> dict:  # fmt: skip
    return {
        "kind": "chunk", "ticket": ticket, "attempt": attempt, "worker": worker,
        "version": version, "seq": seq, "obs": compress_obs(obs), "steps": len(rewards),
        "actions": np.asarray(actions, np.float32), "log_probs": np.asarray(log_probs, np.float32),
        "values": np.asarray(values, np.float32), "rewards": np.asarray(rewards, np.float32),
        "infos": infos, "last": last, "terminated": terminated, "bootstrap": float(bootstrap),
    }  # fmt: skip


def read_chunk(msg: dict, obs_shape: tuple[int, ...], action_dim: int) -> Chunk:
    """A chunk message checked against the spaces the trainer knows (never the worker's)."""
    try:
        steps = checked.integer(msg.get("steps"), "chunk steps", low=1, high=100_000)
        vector = {}
        for name in ("log_probs", "values", "rewards"):
            vector[name] = checked.array(msg.get(name), name, dtype=np.float32, shape=(steps,))
            if not np.isfinite(vector[name]).all():
                raise checked.Malformed(f"{name}: not finite")
        actions = msg.get("actions")
        actions = checked.array(actions, "actions", dtype=np.float32,
                                shape=(steps, action_dim) if action_dim else (steps,))  # fmt: skip
        infos = msg.get("infos")
        if not isinstance(infos, list) or len(infos) != steps:
            raise checked.Malformed("infos: expected one per step")
        bootstrap = checked.number(msg.get("bootstrap", 0.0), "bootstrap")
        return Chunk(
            ticket=checked.text(msg.get("ticket"), "ticket", limit=64),
            attempt=checked.text(msg.get("attempt"), "attempt", limit=64),
            worker=checked.text(msg.get("worker"), "worker", limit=64),
            version=checked.integer(msg.get("version"), "version"),
            seq=checked.integer(msg.get("seq"), "seq", high=1_000_000),
            obs=decompress_obs(msg.get("obs"), (steps, *obs_shape)),
            actions=actions, infos=[checked.mapping(i, "info") for i in infos],
            last=bool(msg.get("last")), terminated=bool(msg.get("terminated")),
            bootstrap=bootstrap, **vector,
        )  # fmt: skip
    except checked.Malformed as exc:
        raise StreamError(f"a simulation worker sent a malformed chunk ({exc})") from None


# ------------------------------------------------------------------------------- sessions
class Session:
    """One training session's keys and the operations both sides use."""

    def __init__(self, redis_url: str, prefix: str, session: str) -> None:
        self.redis_url = redis_url
        self.keys = Keys(prefix, session)
        self.r = client(redis_url)

    # ---- the trainer
    def create(self) -> None:
        self.r.delete(self.keys.exp)
        self.r.xgroup_create(self.keys.exp, GROUP, id="0", mkstream=True)
        self.r.expire(self.keys.exp, KEY_TTL_S)

    def publish_policy(self, version: int, weights: dict[str, np.ndarray], *, episodes: int,
                       evals: list[dict]) -> None:  # fmt: skip
        """Weights of ``version``, then its tickets, then the version number: a worker that
        sees the number finds the weights and tickets already there."""
        k = self.keys
        pipe = self.r.pipeline()
        pipe.set(k.policy(version), pack({"kind": "policy", "weights": weights}), ex=KEY_TTL_S)
        if episodes:
            pipe.rpush(k.tickets(version), *[f"{version}:{i}" for i in range(episodes)])
            pipe.expire(k.tickets(version), KEY_TTL_S)
        if evals:
            pipe.rpush(k.evals(version), *[
                f"e:{version}:{i}:{float(e.get('start_progress', 0.0)):.3f}"
                for i, e in enumerate(evals)
            ])  # fmt: skip
            pipe.expire(k.evals(version), KEY_TTL_S)
        pipe.set(k.version, version, ex=KEY_TTL_S)
        if version >= 2:
            pipe.delete(k.policy(version - 2))
        pipe.execute()

    def withdraw(self, version: int) -> int:
        """Drop the unclaimed tickets of ``version`` (evaluation laps nobody started); returns
        how many evaluation laps were dropped."""
        pipe = self.r.pipeline()
        pipe.llen(self.keys.evals(version))
        pipe.delete(self.keys.evals(version), self.keys.tickets(version))
        return int(pipe.execute()[0])

    def read(self, consumer: str, block_ms: int) -> Iterator[tuple[bytes, dict | StreamError]]:
        """New messages of the experience stream: (id, message or the error it raised)."""
        reply = self.r.xreadgroup(GROUP, consumer, {self.keys.exp: ">"}, count=64,
                                  block=block_ms)  # fmt: skip
        for _stream, entries in reply or []:
            for entry_id, fields in entries:
                body = fields.get(b"m", b"")
                try:
                    yield entry_id, unpack(body)
                except StreamError as exc:
                    yield entry_id, exc

    def ack(self, entry_id: bytes) -> None:
        self.r.xack(self.keys.exp, GROUP, entry_id)

    def alive(self, worker: str) -> bool:
        return bool(self.r.exists(self.keys.alive(worker)))

    def requeue(self, worker: str, counted: set[str], version: int) -> tuple[int, list[str]]:
        """Give a dead worker's claimed tickets back: training tickets of ``version`` not yet
        counted go back to the queue (another worker drives them), others are dropped.
        Returns (training tickets requeued, the evaluation tickets lost with it)."""
        k = self.keys
        requeued, lost = 0, []
        while True:
            item = self.r.lpop(k.claimed(worker))
            if item is None:
                return requeued, lost
            text = item.decode(errors="replace")
            if text.startswith("e:"):
                lost.append(text)
            elif text.split(":")[0] == str(version) and text not in counted:
                self.r.rpush(k.tickets(version), text)
                requeued += 1

    def revoke(self, worker: str) -> None:
        """A worker declared dead (its heartbeat lapsed) must stop, should it still run."""
        self.r.set(self.keys.revoked(worker), 1, ex=KEY_TTL_S)

    def revoked(self, worker: str) -> bool:
        return bool(self.r.exists(self.keys.revoked(worker)))

    def release(self, worker: str) -> int:
        """A stopping worker's unfinished training tickets go back to their queue (the trainer
        counts a ticket once, whoever drives it); returns how many."""
        released = 0
        while True:
            item = self.r.lpop(self.keys.claimed(worker))
            if item is None:
                return released
            text = item.decode(errors="replace")
            if not text.startswith("e:"):
                self.r.rpush(self.keys.tickets(int(text.split(":")[0])), text)
                released += 1

    def set_watch(self, worker: str | None) -> None:
        if worker is None:
            self.r.delete(self.keys.watch)
        else:
            self.r.set(self.keys.watch, worker, ex=3)

    def stop(self) -> None:
        self.r.set(self.keys.stop, 1, ex=KEY_TTL_S)

    def cleanup(self) -> None:
        """Delete the session's keys but ``stop``, which workers still starting must see."""
        keys = [key for key in self.r.scan_iter(match=self.keys.base + "*", count=1000)
                if key != self.keys.stop.encode()]  # fmt: skip
        if keys:
            self.r.delete(*keys)
        self.r.set(self.keys.stop, 1, ex=600)

    # ---- a worker
    def send(self, message: dict) -> None:
        self.r.xadd(self.keys.exp, {"m": pack(message)}, maxlen=EXP_MAXLEN, approximate=True)

    def current_version(self) -> int | None:
        raw = self.r.get(self.keys.version)
        return int(raw) if raw is not None else None

    def policy(self, version: int) -> dict[str, np.ndarray] | None:
        raw = self.r.get(self.keys.policy(version))
        if raw is None:
            return None
        weights = unpack(raw).get("weights")
        if not isinstance(weights, dict):
            raise StreamError("a policy without weights")
        return weights

    def claim(self, worker: str, version: int) -> tuple[str, str] | None:
        """The next ticket of ``version`` for ``worker``: ("train", "<v>:<k>") first, then
        ("eval", "e:<v>:<k>:<start progress>"); None when the version's quota is all taken."""
        k = self.keys
        for kind, key in (("train", k.tickets(version)), ("eval", k.evals(version))):
            item = self.r.lmove(key, k.claimed(worker), "LEFT", "RIGHT")
            if item is not None:
                return kind, item.decode()
        return None

    def done(self, worker: str, item: str | bytes) -> None:
        self.r.lrem(self.keys.claimed(worker), 1, item)

    def heartbeat(self, worker: str) -> None:
        self.r.set(self.keys.alive(worker), 1, px=int(ALIVE_TTL_S * 1000))

    def stopped(self) -> bool:
        return bool(self.r.exists(self.keys.stop))

    def watching(self) -> str | None:
        raw = self.r.get(self.keys.watch)
        return raw.decode() if raw is not None else None

    def send_frame(self, frame: dict) -> None:
        self.r.xadd(self.keys.frames, {"m": pack({"kind": "frame", **frame})},
                    maxlen=FRAMES_MAXLEN, approximate=False)  # fmt: skip

    def read_frames(self, last_id: bytes, block_ms: int) -> list[tuple[bytes, dict]]:
        reply = self.r.xread({self.keys.frames: last_id}, count=16, block=block_ms)
        out = []
        for _stream, entries in reply or []:
            for entry_id, fields in entries:
                try:
                    out.append((entry_id, unpack(fields.get(b"m", b""))))
                except StreamError:
                    out.append((entry_id, {}))
        return out

    def close(self) -> None:
        self.r.close()


def finite(value) -> float:
    """A finite number from a message, else 0."""
    return float(value) if isinstance(value, int | float) and np.isfinite(value) else 0.0


def read_frame(msg: dict) -> dict | None:
    """A frame message checked (JPEG bytes, numbers, a known phase) for the hooks."""
    out = {}
    for key in ("camera", "chase"):
        jpeg = msg.get(key)
        if not isinstance(jpeg, np.ndarray) or jpeg.dtype != np.uint8 or jpeg.ndim != 1:
            return None
        out[key] = jpeg
    phase = msg.get("phase")
    out["phase"] = phase if phase in ("training", "evaluation") else "training"
    for key in ("progress", "lap", "iteration", "version"):
        out[key] = finite(msg.get(key))
    out["lap"], out["iteration"], out["version"] = (int(out[k]) for k in
                                                    ("lap", "iteration", "version"))  # fmt: skip
    return out
