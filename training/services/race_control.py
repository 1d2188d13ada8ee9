"""Controlling a race while it runs: stopping it, and a car's live speed multiplier.

Training owns its race jobs: the league (or anyone else) stops a race or changes a car's
speed through these services, never by writing a job's fields.

**Live speed control** (DeepRacer's LIVE races: the racer set their car's speed during their
turn): :func:`race_speed_set` writes the multiplier of car ``index`` (its entry order) of a
running race to Redis, one key per race job and car with a TTL
(:data:`SPEED_KEY_TTL_S`); the race worker reads every car's key with one ``MGET``
(:class:`RaceSpeeds`), at most every :data:`SPEED_POLL_S` seconds of race clock, and the car
drives the next step at that multiplier. Redis being down never stops a race: the cars keep
the last value read. What each car drives at is written back (:func:`race_speed_applied`),
once when the race starts driving and then only when it changes, so the racer sees their car
took it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from decimal import Decimal, InvalidOperation

import redis
from django.conf import settings
from django.db import transaction
from django.utils import timezone

from training.errors import ServiceError
from training.models import JobStatus, RaceJob
from training.services.job_states import job_ended, transition

log = logging.getLogger(__name__)
MIN_SPEED_MULTIPLIER = 0.5
MAX_SPEED_MULTIPLIER = 1.5
SPEED_MULTIPLIER_STEP = 0.05
"""Multipliers are 0.5-1.5 in steps of 0.05 (DeepRacer's LIVE races offered this range)."""
SPEED_KEY_TTL_S = 60 * 60
"""A speed key outlives any race (races are limited to minutes); then Redis forgets it."""
SPEED_POLL_S = 0.2
"""The race worker reads the multipliers at most this often, in seconds of race clock."""
ACTIVE = (JobStatus.QUEUED, JobStatus.INITIALIZING, JobStatus.IN_PROGRESS)


def _client() -> redis.Redis:
    # Short timeouts: a web request or a paced race loop never hangs on a slow Redis.
    return redis.Redis.from_url(settings.REDIS_URL, socket_timeout=0.5, socket_connect_timeout=0.5)


def speed_key(race_id: int, index: int) -> str:
    return f"{settings.REDIS_PREFIX}racecraft:race-speed:{race_id}:{index}"


def applied_key(race_id: int, index: int) -> str:
    return f"{settings.REDIS_PREFIX}racecraft:race-speed:{race_id}:{index}:applied"


def speed_multiplier_parse(value: object) -> float:
    """``value`` (a number or its text) as a multiplier: 0.5-1.5 in steps of 0.05. Raises
    :class:`ServiceError` with a sentence for anything else."""
    try:
        number = Decimal(str(value).strip())
    except (InvalidOperation, ValueError):
        raise ServiceError(f"the speed must be a number like 1.1, not {str(value)[:20]!r}",
                           field="speed") from None  # fmt: skip
    if not number.is_finite() or not (
        Decimal(str(MIN_SPEED_MULTIPLIER)) <= number <= Decimal(str(MAX_SPEED_MULTIPLIER))
    ):
        raise ServiceError(f"the speed must be between {MIN_SPEED_MULTIPLIER}× and "
                           f"{MAX_SPEED_MULTIPLIER}×", field="speed")  # fmt: skip
    if number % Decimal(str(SPEED_MULTIPLIER_STEP)) != 0:
        raise ServiceError(f"the speed goes in steps of {SPEED_MULTIPLIER_STEP}× "
                           "(for example 0.95 or 1.1)", field="speed")  # fmt: skip
    return float(number)


def race_speed_set(*, race: RaceJob, index: int, multiplier: object) -> float:
    """Set car ``index``'s speed multiplier in running race ``race`` (the caller checked who
    may). Returns the multiplier stored. Raises :class:`ServiceError` for a bad value, a car
    the race does not have, a race that is over, or Redis out of reach."""
    value = speed_multiplier_parse(multiplier)
    if not 0 <= index < len(race.entries):
        raise ServiceError("that car is not in this race")
    if not RaceJob.objects.filter(pk=race.pk, status__in=ACTIVE).exists():
        raise ServiceError("this race is over")
    try:
        _client().set(speed_key(race.pk, index), f"{value:.2f}", ex=SPEED_KEY_TTL_S)
    except redis.RedisError:
        raise ServiceError("the speed could not be sent to the race right now; try again") from None
    return value


def race_speeds(race_id: int, cars: int, client: redis.Redis | None = None) -> list[float | None]:
    """Each car's multiplier as last set (``None``: never set), by entry index. Raises
    ``redis.RedisError`` when Redis is out of reach."""
    if cars <= 0:
        return []
    values = (client or _client()).mget([speed_key(race_id, i) for i in range(cars)])
    out: list[float | None] = []
    for raw in values:
        try:
            number = float(raw) if raw is not None else None
        except ValueError:
            number = None
        ok = number is not None and math.isfinite(number)
        out.append(min(MAX_SPEED_MULTIPLIER, max(MIN_SPEED_MULTIPLIER, number)) if ok else None)
    return out


def race_speed_applied(race_id: int, index: int) -> float | None:
    """The multiplier car ``index`` drives at now, as the race reported it; None before the
    race drives (or when Redis is out of reach)."""
    try:
        raw = _client().get(applied_key(race_id, index))
    except redis.RedisError:
        return None
    return float(raw) if raw is not None else None


def race_speed_of(race_id: int, index: int) -> float:
    """Car ``index``'s multiplier as last set, 1.0 if never set or Redis is out of reach."""
    try:
        value = race_speeds(race_id, index + 1)[index]
    except redis.RedisError:
        return 1.0
    return 1.0 if value is None else value


class RaceSpeeds:
    """The race worker's view of the cars' multipliers. :meth:`reader` gives car ``index``
    the callable its :class:`~racing.racecar.Racer` calls once per step it drives (with the
    race clock): the value comes from a local copy that one ``MGET`` refreshes at most every
    :data:`SPEED_POLL_S` seconds of race clock (never set: 1.0; Redis out of reach: the last
    values), and is logged, one per step (``log[index]``, the trace's column)."""

    def __init__(self, race_id: int, cars: int) -> None:
        self.race_id, self.cars = race_id, cars
        self.values: list[float | None] = [None] * cars
        self.log: list[list[float]] = [[] for _ in range(cars)]
        self._read_at: float | None = None
        self._reported: list[float | None] = [None] * cars
        self._redis = _client()  # one connection for the race

    def value(self, index: int, clock_s: float) -> float:
        if self._read_at is None or clock_s - self._read_at >= SPEED_POLL_S - 1e-9:
            self._read_at = clock_s
            try:
                self.values = race_speeds(self.race_id, self.cars, self._redis)
            except redis.RedisError:
                log.warning("race %s: the speed multipliers could not be read", self.race_id)
        value = self.values[index]
        value = 1.0 if value is None else value
        self.log[index].append(value)
        if value != self._reported[index]:  # the start, then only a change: rare writes
            self._reported[index] = value
            try:
                key = applied_key(self.race_id, index)
                self._redis.set(key, f"{value:.2f}", ex=SPEED_KEY_TTL_S)
            except redis.RedisError:
                log.warning("race %s: the speed applied could not be reported", self.race_id)
        return value

    def reader(self, index: int) -> Callable[[float], float]:
        return lambda clock_s: self.value(index, clock_s)


def race_stop(*, race: RaceJob, by: str = "", cancel_queued: bool = False) -> bool:
    """Stop a race. One a worker has claimed stops at its next step (cooperative: the worker
    polls the flag) and keeps what it drove. One still queued, with ``cancel_queued``, is
    CANCELED at once, as :func:`~training.services.jobs.job_stop` cancels other queued jobs:
    it never runs, it no longer counts against its owner's job quota, and ``race_finished``
    is sent; without it (the race day's stop, which ends its turn when the race ends) it is
    flagged and stops at its first step. ``by`` says who asked, for the log. Returns False
    when the race had already ended; ``race.status`` says whether it was canceled."""
    with transaction.atomic():
        canceled = cancel_queued and transition(
            race, allowed=(JobStatus.QUEUED,), to=JobStatus.CANCELED,
            finished_at=timezone.now(), stop_requested=True,
        )  # fmt: skip
        stopped = canceled or bool(
            RaceJob.objects.filter(pk=race.pk, status__in=ACTIVE).update(stop_requested=True)
        )
    if canceled:
        log.info("race %s: canceled before it ran by %s", race.pk, by or "someone")
        job_ended(race)
    elif stopped:
        race.stop_requested = True
        log.info("race %s: stop requested by %s", race.pk, by or "someone")
    return stopped


__all__ = [
    "MAX_SPEED_MULTIPLIER",
    "MIN_SPEED_MULTIPLIER",
    "SPEED_MULTIPLIER_STEP",
    "RaceSpeeds",
    "race_speed_applied",
    "race_speed_of",
    "race_speed_set",
    "race_speeds",
    "race_stop",
    "speed_multiplier_parse",
]
