"""Reward validation as a Celery task: the web process runs no user code.

``reward_validation_start`` checks the request (text, track, direction: nothing of the user's
is executed), applies the per-user limits and queues ``training.tasks.validate_reward`` on the
``interactive`` queue; the browser polls ``reward_validation_status`` until the result is
there. The worker runs :func:`reward_validation_run` (static checks, then the sandbox) and,
when the function passes, remembers the pass for an hour (:data:`PASS_TTL_S`) under the user,
a hash of the source (line endings aside), the track and the direction.

Saving a reward function from the web (create, clone, reward edit: training/services/
models.py) needs such a pass (:func:`reward_validation_passed`) instead of running the sandbox
in the web process: a function the user just validated saves at once; any other is validated
on the way: :func:`reward_check_before_save` answers a :class:`RewardCheck` (ready,
needs_validation with the id of the validation it queued, or refused); the page shows the
validation's progress and posts the form again when it passes.

Per-user limits live in Redis so every web process sees the same counts: at most
``RACECRAFT_VALIDATIONS_PER_USER`` validations queued or running at once, and at most
``RACECRAFT_VALIDATIONS_PER_MINUTE`` started in a minute. A task id is readable only by the
user who started it.
"""

from __future__ import annotations

import hashlib
import logging
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypedDict

import redis
from celery import current_app
from celery.result import AsyncResult
from django.conf import settings

from training.dispatch import VALIDATE_REWARD
from training.errors import RewardRejected, ServiceError
from training.sandbox import RewardError, check_source
from training.sandbox.static import SOURCE_TOO_LONG, source_too_long
from training.services.checks import check_reward, check_track
from training.services.trackfiles import tracks_sync_for

log = logging.getLogger(__name__)
VALIDATION_QUEUE_DOWN = (
    "the validation could not be queued: the task queue cannot be reached right now; "
    "try again in a minute"
)

#: How long an id stays readable and a slot stays taken without an answer (seconds).
KEY_TTL_S = 15 * 60
#: How long a passed validation lets the same function be saved without another (seconds).
PASS_TTL_S = 60 * 60
REWARD_CHECKS = ("passed", "sandbox", "none")
"""How a reward function is checked before it is saved (training/services/models.py)."""


class ValidationNotFound(ServiceError):
    """No validation with this id belongs to this user."""


class ValidationLimited(ServiceError):
    """The user is over a per-user validation limit (answered 429)."""


class RewardStatus(StrEnum):
    """What a check before saving a reward function found (:class:`RewardCheck`)."""

    READY = "ready"
    """It may be saved now."""
    NEEDS_VALIDATION = "needs_validation"
    """It has no passed validation yet: one is queued on a worker (``task_id``)."""
    REFUSED = "refused"
    """It may not be saved: ``error`` says why (its lines in ``errors``)."""


@dataclass(frozen=True)
class RewardCheck:
    """The answer of :func:`reward_check_before_save`: a value to branch on, never raised.

    ``task_id`` (needs_validation): the validation queued for this user, polled with
    :func:`reward_validation_status`; when it passes, the same save goes through.
    ``error`` (refused): the refusal, a :class:`ServiceError` (a :class:`RewardRejected`
    when the function itself has errors) for a caller to show or raise."""

    status: RewardStatus
    task_id: str = ""
    error: ServiceError | None = None

    @classmethod
    def ready(cls) -> RewardCheck:
        return cls(RewardStatus.READY)

    @classmethod
    def needs_validation(cls, task_id: str) -> RewardCheck:
        return cls(RewardStatus.NEEDS_VALIDATION, task_id=task_id)

    @classmethod
    def refused(cls, error: ServiceError) -> RewardCheck:
        return cls(RewardStatus.REFUSED, error=error)

    @property
    def is_ready(self) -> bool:
        return self.status is RewardStatus.READY

    @property
    def errors(self) -> list[dict[str, Any]]:
        """The reward function's errors on their lines (DeepRacer's dicts); [] otherwise."""
        return list(self.error.errors) if isinstance(self.error, RewardRejected) else []


class ValidationStatus(TypedDict, total=False):
    """``status``: queued | running | done; when done, ``ok``, ``errors`` and ``rewards``."""

    status: str
    ok: bool
    errors: list[dict[str, Any]]
    rewards: dict[str, float]


def _client() -> redis.Redis:
    return redis.Redis.from_url(settings.REDIS_URL)


def _key(*parts: object) -> str:
    return f"{settings.REDIS_PREFIX}racecraft:reward-validation:" + ":".join(map(str, parts))


def _pass_key(user_id: int, source: str, track_id: str, direction: str) -> str:
    """Where a pass is remembered. Line endings are normalised: a browser posts a text box
    with CRLF while the editor's Validate button sends LF, and Python reads both alike."""
    text = source.replace("\r\n", "\n")
    digest = hashlib.sha256("\0".join((text, track_id, direction)).encode()).hexdigest()
    return _key("passed", user_id, digest)


def reward_validation_passed(*, user_id: int, source: str, track_id: str, direction: str) -> bool:
    """Whether this user's validation of exactly this function on this track and direction
    passed within the last :data:`PASS_TTL_S` seconds."""
    client = _client()
    try:
        return bool(client.exists(_pass_key(user_id, source, track_id, direction)))
    except redis.RedisError:  # unknown: the caller starts a validation, which says why not
        log.warning("could not reach Redis for a passed validation", exc_info=True)
        return False
    finally:
        client.close()


def reward_check_before_save(
    *, user, source: str, tracks: Sequence[tuple[str, str]], how: str
) -> RewardCheck:
    """Check ``source`` on each ``(track_id, direction)`` of ``tracks`` as ``how`` says
    (:data:`REWARD_CHECKS`). ``"passed"``: parsing errors and bad requests are refused at
    once; a track without a pass (:func:`reward_validation_passed`) gets a validation queued
    for ``user`` (the first such track; the answer is ``needs_validation`` with its id, or
    ``refused`` when it cannot be queued). Raises only ValueError, for an unknown ``how``."""
    if how not in REWARD_CHECKS:
        raise ValueError(f"reward_check must be one of {REWARD_CHECKS}, not {how!r}")
    try:
        for track_id, direction in tracks if how != "none" else ():
            if how == "sandbox":
                check_reward(source, track_id, direction)
            elif not _passed_on(user, source, track_id, direction):
                return _validation_queued(user, source, track_id, direction)
    except ServiceError as exc:
        return RewardCheck.refused(exc)
    return RewardCheck.ready()


def _passed_on(user, source: str, track_id: str, direction: str) -> bool:
    """Whether ``source`` has a pass on the track; raises ServiceError (RewardRejected with
    its lines) for a request or a source refused before anything runs."""
    _check_request(source, track_id, direction)
    static = check_source(source)  # parsing only: no user code runs here
    if static:
        raise RewardRejected(static)
    return reward_validation_passed(
        user_id=user.pk, source=source, track_id=track_id, direction=direction
    )


def _validation_queued(user, source: str, track_id: str, direction: str) -> RewardCheck:
    try:
        task_id = reward_validation_start(
            user_id=user.pk, source=source, track_id=track_id, direction=direction
        )
    except ServiceError as exc:  # over a limit, or the queue down: shown on the editor
        return RewardCheck.refused(ServiceError(exc.message, field="reward_function"))
    return RewardCheck.needs_validation(task_id)


def reward_parse_errors(*, source: str) -> list[dict]:
    """The errors parsing alone finds in ``source`` (DeepRacer's error dicts, in source
    order): none for a blank source or one that may run. No user code runs here."""
    return [e.to_dict() for e in check_source(source)] if source.strip() else []


def reward_too_long_error() -> dict:
    """The error every check gives a source longer than the most a reward function may have
    (for a request refused by its size before it is read)."""
    return RewardError("SYNTAX_ERROR", SOURCE_TOO_LONG).to_dict()


def reward_validation_remember(*, user_id: int, source: str, track_id: str, direction: str) -> None:
    """Remember a passed validation (the worker, after the sandbox ran the function)."""
    client = _client()
    try:
        client.set(_pass_key(user_id, source, track_id, direction), 1, ex=PASS_TTL_S)
    finally:
        client.close()


def _check_request(source: object, track_id: object, direction: object) -> None:
    if not isinstance(source, str) or not source.strip():
        raise ServiceError("write a reward function", field="reward_function")
    if (too_long := source_too_long(source)) is not None:
        raise RewardRejected([too_long])
    if not isinstance(track_id, str) or not isinstance(direction, str):
        raise ServiceError("choose a track and a direction", field="track_id")
    check_track(track_id, direction)


def _take_slot(client: redis.Redis, user_id: int) -> None:
    """Count this start against the user's per-minute and concurrent limits, or refuse."""
    per_minute = settings.RACECRAFT_VALIDATIONS_PER_MINUTE
    window = _key("rate", user_id, int(time.time() // 60))
    started = client.incr(window)
    client.expire(window, 120)
    if started > per_minute:
        raise ValidationLimited(
            f"you started {per_minute} validations in the last minute, the most allowed; "
            "wait a moment"
        )
    active = _key("active", user_id)
    for task_id in client.smembers(active):
        if AsyncResult(task_id.decode(), app=current_app).ready():
            client.srem(active, task_id)
    limit = settings.RACECRAFT_VALIDATIONS_PER_USER
    if client.scard(active) >= limit:
        raise ValidationLimited(f"you have {limit} validations running; wait for one to finish")


def reward_validation_start(*, user_id: int, source: str, track_id: str, direction: str) -> str:
    """Queue a validation of ``source`` on the track; return its id. Raises ServiceError for
    a request we refuse (bad input, over a limit, the queue unreachable)."""
    _check_request(source, track_id, direction)
    client = _client()
    try:
        _take_slot(client, user_id)
        task_id = uuid.uuid4().hex
        client.set(_key("owner", task_id), user_id, ex=KEY_TTL_S)
        client.sadd(_key("active", user_id), task_id)
        client.expire(_key("active", user_id), KEY_TTL_S)
        try:
            current_app.send_task(
                VALIDATE_REWARD, kwargs={"source": source, "track_id": track_id,
                                   "direction": direction, "user_id": user_id},
                task_id=task_id,
            )  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - a task that cannot be queued is refused
            log.warning("could not queue a validation", exc_info=True)
            client.srem(_key("active", user_id), task_id)
            raise ServiceError(VALIDATION_QUEUE_DOWN) from exc
    except redis.RedisError as exc:  # Redis holds the limits and the queue: both unreachable
        log.warning("could not reach Redis for a validation", exc_info=True)
        raise ServiceError(VALIDATION_QUEUE_DOWN) from exc
    finally:
        client.close()
    return task_id


def reward_validation_status(*, user_id: int, task_id: str) -> ValidationStatus:
    """Where the user's validation ``task_id`` is; raises ValidationNotFound for an id that is
    not theirs (or too old)."""
    client = _client()
    try:
        owner = client.get(_key("owner", task_id)) if isinstance(task_id, str) else None
        if owner is None or owner.decode() != str(user_id):
            raise ValidationNotFound("no such validation")
        result = AsyncResult(task_id, app=current_app)
        if not result.ready():
            return {"status": "running" if result.state == "STARTED" else "queued"}
        client.srem(_key("active", user_id), task_id)
    finally:
        client.close()
    if result.successful() and isinstance(result.result, dict):
        return {"status": "done", **result.result}
    failed = {"type": "TEST_FAILURE", "message": "The validation could not finish; try again.",
              "line": None, "lineNumber": None, "column": None}  # fmt: skip
    return {"status": "done", "ok": False, "errors": [failed], "rewards": {}}


def reward_validation_run(
    *, source: str, track_id: str, direction: str, user_id: int | None = None
) -> dict[str, Any]:
    """In the worker: validate and answer ``{ok, errors, rewards}`` (JSON-able); a pass is
    remembered for ``user_id`` (:func:`reward_validation_passed`)."""
    tracks_sync_for([track_id])  # this worker may share no disk with the web that took the upload
    try:
        result = check_reward(source, track_id, direction)
    except RewardRejected as exc:
        return {"ok": False, "errors": exc.errors, "rewards": {}}
    except ServiceError as exc:
        error = {"type": "REQUEST_ERROR", "message": exc.sentence, "line": None,
                 "lineNumber": None, "column": None, "field": exc.field}  # fmt: skip
        return {"ok": False, "errors": [error], "rewards": {}}
    if user_id is not None:
        reward_validation_remember(
            user_id=user_id, source=source, track_id=track_id, direction=direction
        )
    return {"ok": True, "errors": [], "rewards": result["rewards"]}
