"""Racers racing each other from the browser (the Races page): who may race what, the race's
limits, and who sees what of it afterwards.

- A racer races one of **their own** models with a trained checkpoint against one to three
  opponents: their own models, or other racers' models whose owners opened them to
  challenges (:attr:`RacingModel.open_to_challenges`, off by default).
- Every car races a **frozen copy** of its model's best checkpoint, taken when the race is
  queued (``league/race-<race id>/<model id>.zip``, as a league entry's), with the model's
  metadata kept in the entry: closing, retraining or deleting a model later changes nothing in
  the race, and its results and replay stay.
- Limits: 1-5 laps, 0-6 bot cars, a loop from the track catalogue, a direction.
- The race is a race job charged to the challenger (their job quota,
  ``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER``) and dealt in the fair order
  (:mod:`training.services.job_queue`).
- The challenger stops their race (:func:`challenge_stop`): a queued one is canceled at once
  (it never runs and gives its quota share back), a running one stops at its next step.
- The challenger (:attr:`RaceJob.owner`) sees the race's page, live view, results, replay and
  sim-traces; an opponent's owner (:attr:`RaceJob.opponents`) sees the result and the replay;
  anyone else, nothing.
"""

from __future__ import annotations

import io
import tarfile
from collections.abc import Sequence
from dataclasses import dataclass

from django.db import transaction
from django.db.models import Q, QuerySet

from racing.headtohead import MAX_RACERS
from training import dispatch
from training.errors import ServiceError, StoreError
from training.interchange.layout import RaceKeys
from training.models import JobStatus, RaceJob, RacingModel
from training.services.job_queue import jobs_ahead
from training.services.job_states import enqueue_after_commit
from training.services.jobs import job_quota_hold
from training.services.model_files import model_freeze, model_metadata, store_failure
from training.services.race_control import race_stop
from training.services.races import RACE_DEFAULT_BOT_SPEED, race_conditions
from training.store import get_store

CHALLENGE = "challenge"
"""``RaceJob.purpose`` of a race started from the Races page."""
MIN_OPPONENTS, MAX_OPPONENTS = 1, MAX_RACERS - 1
MIN_LAPS, MAX_LAPS = 1, 5
MIN_BOTS, MAX_BOTS = 0, 6
DIRECTIONS = ("native", "ccw", "cw")


@dataclass(frozen=True)
class ChallengeChoices:
    """What the New race form offers ``user``: their models that can race, and the opponents
    (their own such models, then others' open ones)."""

    mine: list[RacingModel]
    opponents: list[RacingModel]


def _raceable() -> QuerySet[RacingModel]:
    return RacingModel.objects.filter(has_checkpoint=True).exclude(
        status=RacingModel.Status.DELETING
    )


def challenge_choices(*, user) -> ChallengeChoices:
    mine = list(_raceable().filter(owner=user).order_by("name"))
    others = list(
        _raceable()
        .filter(open_to_challenges=True)
        .exclude(owner=user)
        .select_related("owner")
        .order_by("owner__username", "name")
    )
    return ChallengeChoices(mine=mine, opponents=mine + others)


def model_challenges_set(*, model: RacingModel, user, open_: bool) -> RacingModel:
    """Open (or close) ``model`` to other racers' challenges; only its owner may. Races
    already run or queued keep their frozen copies whatever is chosen later."""
    if model.owner_id != getattr(user, "pk", None):
        raise ServiceError("not found")
    RacingModel.objects.filter(pk=model.pk).update(open_to_challenges=bool(open_))
    model.open_to_challenges = bool(open_)
    return model


def _int_in(value: object, low: int, high: int, what: str, field: str) -> int:
    try:
        number = int(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ServiceError(f"{what} must be a whole number from {low} to {high}",
                           field=field) from None  # fmt: skip
    if not low <= number <= high:
        raise ServiceError(f"{what} must be {low} to {high}, not {number}", field=field)
    return number


def _entrants(user, model_id: int, opponent_ids: Sequence[int]) -> list[RacingModel]:
    """The racer's model then the opponents, checked (see the module's rules)."""
    ids = [int(i) for i in opponent_ids]
    if not MIN_OPPONENTS <= len(ids) <= MAX_OPPONENTS:
        raise ServiceError(f"pick {MIN_OPPONENTS} to {MAX_OPPONENTS} opponents, not {len(ids)}",
                           field="opponents")  # fmt: skip
    if len(set(ids)) != len(ids) or int(model_id) in ids:
        raise ServiceError("a model can take only one place on the grid: pick each once, and "
                           "not your own car as its opponent", field="opponents")  # fmt: skip
    found = {m.pk: m for m in RacingModel.objects.filter(pk__in=[model_id, *ids])
             .select_related("owner")}  # fmt: skip
    mine = found.get(int(model_id))
    if mine is None or mine.owner_id != user.pk:
        raise ServiceError("pick one of your own models to race", field="model")
    if not mine.has_checkpoint or mine.status == RacingModel.Status.DELETING:
        raise ServiceError(f"{mine.name} has no trained checkpoint to race yet; train it first",
                           field="model")  # fmt: skip
    opponents = []
    for pk in ids:
        model = found.get(pk)
        if model is None or (model.owner_id != user.pk and not model.open_to_challenges):
            # Never say whether a closed model exists: its owner keeps it to themselves.
            raise ServiceError(f"model #{pk} is not open to challenges (its owner may have "
                               "closed it); pick another opponent", field="opponents")  # fmt: skip
        if not model.has_checkpoint or model.status == RacingModel.Status.DELETING:
            raise ServiceError(f"{model.name} has no trained checkpoint to race",
                               field="opponents")  # fmt: skip
        opponents.append(model)
    return [mine, *opponents]


def challenge_start(
    *,
    user,
    model_id: int,
    opponent_ids: Sequence[int],
    track_id: str,
    direction: str = "native",
    laps: int = 3,
    bots: int = 0,
) -> RaceJob:
    """Queue a race of the racer's model ``model_id`` against ``opponent_ids`` (see the
    module's rules), charged to ``user``: raises :class:`ServiceError` naming the form field,
    or :class:`~training.services.jobs.JobQuotaError` when their job quota is full. Nothing
    is created when refused."""
    if not getattr(user, "pk", None):
        raise ServiceError("log in to race")
    laps = _int_in(laps, MIN_LAPS, MAX_LAPS, "laps", "laps")
    bots = _int_in(bots, MIN_BOTS, MAX_BOTS, "bot cars", "bots")
    if direction not in DIRECTIONS:
        raise ServiceError("direction must be native, ccw or cw", field="direction")
    models = _entrants(user, model_id, opponent_ids)
    race, settings = race_conditions(track_id=track_id, cars=len(models), direction=direction,
                                     laps=laps, bots=bots)  # fmt: skip
    entries = [
        {"model": m.pk, "name": m.name, "owner": m.owner_id, "owner_name": m.owner.username,
         "metadata": model_metadata(m).to_json()}
        for m in models
    ]  # fmt: skip
    title = " v ".join(m.name for m in models)
    with transaction.atomic():
        job_quota_hold(user=user)
        job = RaceJob.objects.create(
            owner=user, title=title[:120], purpose=CHALLENGE, entries=entries,
            track_id=track_id, direction=direction, laps=settings.laps,
            bots=race.number_of_bots if race.has_bots else 0,
            bot_speed=race.bot_speed if race.has_bots else RACE_DEFAULT_BOT_SPEED,
            seed=settings.seed, off_track_penalty_s=settings.off_track_penalty_s,
            crash_penalty_s=settings.crash_penalty_s,
        )  # fmt: skip
        try:  # the weights each car races with, whatever happens to its model from now on
            for entry, model in zip(entries, models, strict=True):
                entry["checkpoint"] = model_freeze(model=model, scope=f"race-{job.pk}",
                                                   entry=model.pk)  # fmt: skip
        except StoreError as exc:
            _forget_frozen(job.pk)
            raise store_failure(exc, "the race could not keep its cars' checkpoints") from None
        RaceJob.objects.filter(pk=job.pk).update(entries=entries)
        job.entries = entries
        job.opponents.set({m.owner_id for m in models[1:]} - {user.pk})
        enqueue_after_commit(job, dispatch.EVALUATE_RACE)
    return job


STOPPING, CANCELED, ENDED = "stopping", "canceled", "ended"


def challenge_stop(*, race: RaceJob, by: str = "") -> str:
    """The challenger stops their race (the caller checked who may, :func:`challenge_for`).
    A race still queued is canceled at once (:func:`race_stop`): it never runs, its job
    quota share is free again, and its frozen checkpoints are deleted after the commit (no
    car will race them). A running race stops at its next step and keeps what it drove.
    Returns :data:`CANCELED`, :data:`STOPPING` or :data:`ENDED` (it had already ended)."""
    if not race_stop(race=race, by=by, cancel_queued=True):
        return ENDED
    if race.status == JobStatus.CANCELED:
        race_id = race.pk
        transaction.on_commit(lambda: _forget_frozen(race_id))
        return CANCELED
    return STOPPING


def _forget_frozen(race_id: int) -> None:
    try:
        get_store().delete_prefix(f"league/race-{race_id}/")
    except StoreError:
        pass  # an orphan copy costs only space


# ------------------------------------------------------------------------------ reads
CHALLENGER, OPPONENT = "challenger", "opponent"


def challenge_role(race: RaceJob, user) -> str | None:
    """``"challenger"`` (the racer who started it), ``"opponent"`` (an opponent's owner) or
    None: what ``user`` may see of a race from the Races page."""
    if race.purpose != CHALLENGE or not getattr(user, "pk", None):
        return None
    if race.owner_id == user.pk:
        return CHALLENGER
    if race.opponents.filter(pk=user.pk).exists():
        return OPPONENT
    return None


def challenge_for(*, user, race_id: int, challenger_only: bool = False) -> tuple[RaceJob, str]:
    """The race and ``user``'s role in it; raises ``RaceJob.DoesNotExist`` for anyone else
    (the web answers 404, as for a missing race)."""
    race = RaceJob.objects.select_related("owner").filter(pk=race_id, purpose=CHALLENGE).first()
    role = challenge_role(race, user) if race is not None else None
    if role is None or (challenger_only and role != CHALLENGER):
        raise RaceJob.DoesNotExist
    return race, role


def races_started_by(*, user, limit: int = 50) -> list[RaceJob]:
    return list(
        RaceJob.objects.filter(purpose=CHALLENGE, owner=user).order_by("-created_at", "-pk")[:limit]
    )


def races_against(*, user, limit: int = 50) -> list[dict]:
    """Races where one of ``user``'s models was an opponent: the race, the challenger's name,
    and each of ``user``'s cars in it with its finishing row (once finished)."""
    rows = []
    races = (RaceJob.objects.filter(Q(purpose=CHALLENGE) & Q(opponents=user))
             .select_related("owner").order_by("-created_at", "-pk")[:limit])  # fmt: skip
    for race in races:
        cars = {int(car.get("model", 0)): car for car in race.car_rows}
        mine = [{"name": e.get("name", ""), "result": cars.get(int(e["model"]))}
                for e in race.entries[1:] if e.get("owner") == user.pk]  # fmt: skip
        rows.append({"race": race, "challenger": race.owner.username if race.owner else "—",
                     "mine": mine})  # fmt: skip
    return rows


def jobs_ahead_of(race: RaceJob) -> int | None:
    """How many queued races run before this one in the fair order (None unless queued)."""
    return jobs_ahead(race)


def result_rows(race: RaceJob) -> list[dict]:
    """The finished race's cars in finishing order, each with its owner's name."""
    owners = {int(e["model"]): e.get("owner_name", "") for e in race.entries}
    return [{**car, "owner_name": owners.get(int(car.get("model", 0)), "")}
            for car in race.car_rows]  # fmt: skip


def challenge_traces(race: RaceJob) -> bytes:
    """Every car's sim-trace and metadata of the race (``races/<id>/``), as a ``.tar.gz``
    laid out as the store keeps it (deepracer-utils reads each car's folder as a model's).
    Raises :class:`ServiceError` when the race has none or the store fails."""
    store, prefix = get_store(), RaceKeys(race.pk).prefix
    buffer = io.BytesIO()
    try:
        keys = [k for k in store.list(prefix) if not k.endswith(".mp4")]
        if not keys:
            raise ServiceError("this race has no sim-traces (it has not finished)")
        with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
            for key in sorted(keys):
                data = store.get_bytes(key)
                info = tarfile.TarInfo(f"race-{race.pk}/{key[len(prefix) :]}")
                info.size = len(data)
                archive.addfile(info, io.BytesIO(data))
    except StoreError as exc:
        raise store_failure(exc, "the race's sim-traces could not be read") from None
    return buffer.getvalue()
