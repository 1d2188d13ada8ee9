"""Rollout workers on other machines: the same sandboxed simulation, reached through Redis.

When one machine is not enough, ``celery -A console worker -Q simulation`` on more machines
serves rollouts. The trainer queues one :func:`serve_rollout` task per slot; each task starts a
sandboxed worker (:mod:`training.rollout.vecenv`) on its own machine and relays the trainer's
commands and the worker's replies through two Redis lists. Messages keep the sandbox's format
(JSON and raw arrays, never pickles) end to end, so :class:`RemoteVecEnv` gets exactly what a local
:class:`~training.rollout.vecenv.SandboxedVecEnv` gets, and the same seed gives the same episodes.
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Callable
from typing import Any

import redis

from training.rollout.envs import EnvSpec
from training.rollout.vecenv import (
    ROLLOUT_LIMITS,
    STEP_TIMEOUT_S,
    WORKER_MAIN,
    WORKER_PREPARE,
    RolloutError,
    _WorkerVecEnv,
    first_envs,
    reply_timeout,
)
from training.sandbox import SandboxCrashed, SandboxProcess, checked
from training.sandbox.protocol import ProtocolError, decode, encode

log = logging.getLogger(__name__)
LaunchWorker = Callable[..., None]
"""Starts one :func:`serve_rollout` on a simulation machine with the given keyword arguments."""
START_TIMEOUT_S = 120.0
IDLE_TIMEOUT_S = 600.0
KEY_TTL_S = 3600


def _client(redis_url: str) -> redis.Redis:
    """A client whose socket waits longer than our longest blocking pop: redis-py's default
    read timeout (5 s in redis-py 8) would end a pop that is still legitimately waiting for a
    slow step on a loaded machine ("Timeout reading from socket")."""
    longest_pop = max(START_TIMEOUT_S, STEP_TIMEOUT_S, IDLE_TIMEOUT_S)
    return redis.Redis.from_url(redis_url, socket_timeout=longest_pop + 30)


def _keys(prefix: str, session: str, slot: int) -> tuple[str, str]:
    base = f"{prefix}racecraft:rollout:{session}:{slot}"
    return f"{base}:cmd", f"{base}:reply"


def _client(redis_url: str) -> redis.Redis:
    """A client whose socket timeout outlasts the longest blocking pop (redis-py's default, 5 s,
    would end a BLPOP of a slow step with "Timeout reading from socket")."""
    longest = max(IDLE_TIMEOUT_S, START_TIMEOUT_S, STEP_TIMEOUT_S)
    return redis.Redis.from_url(redis_url, socket_timeout=longest + 30, socket_connect_timeout=10)


def _push(client: redis.Redis, key: str, message: Any) -> None:
    pipe = client.pipeline()
    pipe.rpush(key, encode(message))
    pipe.expire(key, KEY_TTL_S)
    pipe.execute()


def _pop(client: redis.Redis, key: str, timeout: float) -> Any | None:
    item = client.blpop([key], timeout=max(1, int(timeout)))
    if item is None:
        return None
    frame = item[1]
    return decode(frame[4:])


# --------------------------------------------------------------------------- worker side
def serve_rollout(*, redis_url: str, prefix: str, session: str, slot: int, args: dict,
                  reward_source: str) -> str:  # fmt: skip
    """Run on a simulation machine: a sandboxed rollout worker, bridged to Redis."""
    client = _client(redis_url)
    cmd_key, reply_key = _keys(prefix, session, slot)
    worker = SandboxProcess(
        target=WORKER_MAIN,
        prepare=WORKER_PREPARE,
        reward_source=reward_source,
        args=args,
        limits=ROLLOUT_LIMITS,
    )
    try:
        worker.start()
    except Exception as exc:  # noqa: BLE001 - tell the trainer, in words
        _push(client, reply_key, {"kind": "error", "message": str(exc)})
        return "failed"
    _push(client, reply_key, {"kind": "ready", "layers": worker.layers})
    try:
        while True:
            msg = _pop(client, cmd_key, IDLE_TIMEOUT_S)
            if msg is None:
                log.warning("rollout %s/%s: the trainer went quiet; stopping", session, slot)
                return "idle"
            if not isinstance(msg, dict):
                continue
            worker.send(msg)
            if msg.get("cmd") == "close":
                return "closed"
            try:
                cmd = str(msg.get("cmd"))
                reply = worker.recv(timeout=reply_timeout(cmd, args["num_envs"], worker.limits))
            except SandboxCrashed as exc:
                _push(client, reply_key, {"kind": "error", "message": str(exc)})
                return "failed"
            _push(client, reply_key, {"kind": "message", "value": reply.value})
    finally:
        worker.close(grace_seconds=2.0)
        client.close()


# --------------------------------------------------------------------------- trainer side
class RemoteSlot:
    """One remote worker as the trainer sees it: send a command, receive its reply."""

    def __init__(self, client: redis.Redis, prefix: str, session: str, slot: int) -> None:
        self.client = client
        self.cmd_key, self.reply_key = _keys(prefix, session, slot)

    def send(self, message: dict) -> None:
        _push(self.client, self.cmd_key, message)

    def recv(self, timeout: float) -> dict:
        try:
            msg = _pop(self.client, self.reply_key, timeout)
        except ProtocolError as exc:
            raise RolloutError(f"a simulation worker sent malformed data ({exc})") from None
        except redis.RedisError as exc:
            raise RolloutError(f"lost the connection to Redis: {exc}") from None
        if msg is None:
            raise RolloutError(f"a simulation worker gave no answer within {timeout:g} s")
        kind = msg.get("kind") if isinstance(msg, dict) else None
        if kind not in ("ready", "message", "error"):
            raise RolloutError("a simulation worker sent malformed data")
        if kind == "error":
            text = msg.get("message")
            if not isinstance(text, str):
                raise RolloutError("a simulation worker sent malformed data")
            raise RolloutError(text[: checked.MAX_TEXT] or "a simulation worker failed")
        return msg


class RemoteVecEnv(_WorkerVecEnv):
    """``num_envs`` envs spread over ``num_slots`` rollout workers on the ``simulation`` queue.

    Raises :class:`RolloutError` in plain words when no simulation worker takes the work or one
    fails; the reward's own errors come through as they do locally.
    """

    def __init__(self, spec: EnvSpec, num_envs: int, reward_source: str, *, launch: LaunchWorker,
                 num_slots: int, redis_url: str, prefix: str = "",
                 phase: str = "training") -> None:  # fmt: skip
        num_slots = max(1, min(num_slots, num_envs))
        self.sizes = [num_envs // num_slots + (1 if i < num_envs % num_slots else 0)
                      for i in range(num_slots)]  # fmt: skip
        probe = spec.make(None)
        obs_space, act_space = probe.observation_space, probe.action_space
        probe.close()
        self.client = _client(redis_url)
        session = uuid.uuid4().hex
        self.slots = [RemoteSlot(self.client, prefix, session, i) for i in range(num_slots)]
        for i, (first, size) in enumerate(zip(first_envs(self.sizes), self.sizes, strict=True)):
            launch(
                redis_url=redis_url, prefix=prefix, session=session, slot=i,
                args={"spec": spec.to_json(), "num_envs": size, "phase": phase,
                      "first_env": first},
                reward_source=reward_source,
            )  # fmt: skip
        started = time.monotonic()
        for slot in self.slots:
            left = START_TIMEOUT_S - (time.monotonic() - started)
            try:
                msg = slot.recv(max(1.0, left))
            except RolloutError as exc:
                self._abandon()
                if "no answer" in str(exc):
                    raise RolloutError(
                        "no simulation worker took the rollout within "
                        f"{START_TIMEOUT_S:.0f} s: start one with "
                        "`celery -A console worker -Q simulation`"
                    ) from None
                raise
            if msg.get("kind") != "ready":
                self._abandon()
                raise RolloutError("a simulation worker did not start as expected")
        super().__init__(num_envs, obs_space, act_space)

    def _abandon(self) -> None:
        for slot in self.slots:
            try:
                slot.send({"cmd": "close"})
            except redis.RedisError:
                pass

    def _exchange(self, messages: list[dict]) -> list[dict]:
        for slot, msg in zip(self.slots, messages, strict=True):
            slot.send(msg)
        replies = []
        for slot in self.slots:
            msg = slot.recv(STEP_TIMEOUT_S)
            value = msg.get("value")
            if msg.get("kind") != "message" or not isinstance(value, dict):
                raise RolloutError("a simulation worker sent malformed data")
            replies.append(value)
        return replies

    def close(self) -> None:
        self._abandon()
        self.client.close()
