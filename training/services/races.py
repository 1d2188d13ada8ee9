"""Head-to-head races: what a race of racers' models needs before it is run, checked where it is
decided (the command line, a race job, the league), with messages a user can act on."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from django.db import transaction

from racing.headtohead import MAX_RACERS, MIN_RACERS, grid_length_m
from racing.objects import spread
from racing.race import RaceConfig
from racing.track import TrackError
from training import dispatch
from training.errors import ServiceError
from training.models import RaceJob, RacingModel
from training.rl.race import RaceError, RaceSettings
from training.services.checks import track_catalog
from training.services.conditions import conditions_drawn_check
from training.services.job_states import enqueue_after_commit
from training.services.jobs import job_quota_hold
from training.services.model_files import model_metadata
from training.services.racing import race_settings
from training.services.trackfiles import tracks_sync_for

RACE_DEFAULT_BOT_SPEED = 0.75
"""DeepRacer's 2020 head-to-head qualifying: 6 bots at 0.75 m/s."""


@dataclass(frozen=True)
class RacePlan:
    """A race ready to run: its models in entry order, track, direction, bots and settings."""

    models: tuple[RacingModel, ...]
    track_id: str
    direction: str
    race: RaceConfig
    settings: RaceSettings


def race_plan(
    *,
    model_ids: Sequence[int],
    track_id: str,
    solo: bool = False,
    **conditions,
) -> RacePlan:
    """Check a race of ``model_ids`` (2-4 different models, each racing with its own sensors
    and action space; with ``solo`` one alone, a race day's time trial) on ``track_id`` under
    ``conditions`` (:func:`race_conditions`); raises :class:`ServiceError` naming what is
    wrong."""
    ids = list(model_ids)
    least = MIN_RACERS if solo else 2
    if not least <= len(ids) <= MAX_RACERS:
        raise ServiceError(f"a race has {least} to {MAX_RACERS} models, not {len(ids)}",
                           field="models")  # fmt: skip
    if len(set(ids)) != len(ids):
        raise ServiceError("a model can take only one place on the grid", field="models")
    found = {model.pk: model for model in RacingModel.objects.filter(pk__in=ids)}
    missing = [str(i) for i in ids if i not in found]
    if missing:
        raise ServiceError(f"no model with id {', '.join(missing)}", field="models")
    race, settings = race_conditions(track_id=track_id, cars=len(ids), **conditions)
    direction = conditions.get("direction", "native")
    return RacePlan(tuple(found[i] for i in ids), track_id, direction, race, settings)


def race_conditions(
    *,
    track_id: str,
    cars: int,
    direction: str = "native",
    laps: int = 3,
    bots: int = 0,
    bot_speed: float = RACE_DEFAULT_BOT_SPEED,
    seed: int = 0,
    round_number: int = 0,
    off_track_penalty_s: float = 5.0,
    crash_penalty_s: float = 5.0,
    time_limit_s: float | None = None,
    record_video: bool = True,
) -> tuple[RaceConfig, RaceSettings]:
    """The race's bots and settings, checked for ``cars`` cars on ``track_id`` (a loop the
    bots fit on, ahead of the grid); raises :class:`ServiceError`."""
    if direction not in ("native", "ccw", "cw"):
        raise ServiceError("direction must be native, ccw or cw", field="direction")
    tracks_sync_for([track_id])
    try:
        track = track_catalog().load(track_id)
    except (KeyError, TrackError, OSError, ValueError):
        raise ServiceError(f"unknown track {track_id!r}", field="track_id") from None
    if not track.closed:
        raise ServiceError(f"track {track_id!r} is not a loop: head-to-head races need one",
                           field="track_id")  # fmt: skip
    race = RaceConfig()
    if bots:
        stored = race_settings("HEAD_TO_BOT", {"number_of_bots": bots, "bot_speed": bot_speed})
        race = RaceConfig.from_dict(stored)
        try:
            clear = grid_length_m(cars)
            spread(track.length - clear, race.number_of_bots, race.min_bot_gap_m, None)
        except ValueError as exc:
            raise ServiceError(str(exc), field="bots") from None
    try:
        settings = RaceSettings(
            laps=laps,
            off_track_penalty_s=off_track_penalty_s,
            crash_penalty_s=crash_penalty_s,
            time_limit_s=time_limit_s,
            seed=seed,
            round=round_number,
            record_video=record_video,
        )
    except RaceError as exc:
        raise ServiceError(str(exc), field="laps") from None
    return race, settings


def race_start_entries(
    *,
    entries: list[dict],
    track_id: str,
    title: str = "",
    paced: bool = False,
    broadcast_group: str = "",
    charged_to=None,
    world: dict | None = None,
    **conditions,
) -> RaceJob:
    """Queue a league race of entries already frozen by the league (``{"model", "name",
    "checkpoint", "metadata", "tag"}``: the model may be deleted since, the race does not
    need it); the league checked who may run it. ``charged_to``: the user whose job quota
    the race counts against (its owner; a community event's organiser), or None (a public
    event's: the operator's own league). ``world``: the outside-world conditions every car's
    camera sees (one draw, ``Conditions.to_dict()``; a league event's), None: clean. Raises
    :class:`ServiceError`, and
    :class:`~training.services.jobs.JobQuotaError` when ``charged_to`` has no job to spare
    (nothing is queued then)."""
    if not MIN_RACERS <= len(entries) <= MAX_RACERS:
        raise ServiceError(f"a race has {MIN_RACERS} to {MAX_RACERS} cars, not {len(entries)}")
    race, settings = race_conditions(track_id=track_id, cars=len(entries), **conditions)
    direction = conditions.get("direction", "native")
    return _create(entries=entries, track_id=track_id, direction=direction, race=race,
                   settings=settings, user=charged_to, title=title, purpose="league", paced=paced,
                   broadcast_group=broadcast_group, enqueue=True,
                   world=conditions_drawn_check(world))  # fmt: skip


def race_start(
    *,
    plan: RacePlan,
    user,
    title: str = "",
    purpose: str = "race",
    checkpoints: dict[int, str] | None = None,
    tags: dict[int, object] | None = None,
    paced: bool = False,
    broadcast_group: str = "",
    enqueue: bool = True,
) -> RaceJob:
    """Queue ``plan`` as a race job for an evaluation worker. A user races their own models;
    racing other people's takes staff rights, or a league service (``purpose="league"``)
    that checked the facilitator's role and froze each entry's weights (``checkpoints``:
    model id → store key). ``tags``: model id → what the caller knows the entry as (a
    submission's id), kept in the entry. ``paced``: at real time, its frames also sent to
    ``broadcast_group`` (a race day's broadcast page). A race queued for a worker counts
    against ``user``'s job quota (:class:`~training.services.jobs.JobQuotaError`)."""
    owners = {model.owner_id for model in plan.models}
    mine = owners == {getattr(user, "pk", None)}
    if purpose != "league" and not mine and not getattr(user, "is_staff", False):
        raise ServiceError("you can race only your own models", field="models")
    frozen = checkpoints or {}
    entries = [{"model": m.pk, "name": m.name, "checkpoint": frozen.get(m.pk, "")}
               for m in plan.models]  # fmt: skip
    for entry, model in zip(entries, plan.models, strict=True):
        if tags and model.pk in tags:
            entry["tag"] = tags[model.pk]
        if entry["checkpoint"]:  # frozen: the metadata too, so the entry outlives its model
            entry["metadata"] = model_metadata(model).to_json()
    return _create(entries=entries, track_id=plan.track_id, direction=plan.direction,
                   race=plan.race, settings=plan.settings, user=user, title=title,
                   purpose=purpose, paced=paced, broadcast_group=broadcast_group,
                   enqueue=enqueue)  # fmt: skip


def _create(*, entries: list[dict], track_id: str, direction: str, race: RaceConfig,
            settings: RaceSettings, user, title: str, purpose: str, paced: bool,
            broadcast_group: str, enqueue: bool, world: dict | None = None) -> RaceJob:  # fmt: skip
    owner = user if getattr(user, "pk", None) else None
    with transaction.atomic():
        if owner is not None and enqueue:  # a race run here by the command line is not queued
            job_quota_hold(user=owner)
        job = RaceJob.objects.create(
            owner=owner, title=title[:120],
            purpose=purpose, entries=entries, track_id=track_id, direction=direction,
            laps=settings.laps, bots=race.number_of_bots if race.has_bots else 0,
            bot_speed=race.bot_speed if race.has_bots else RACE_DEFAULT_BOT_SPEED,
            seed=settings.seed, round_number=settings.round,
            off_track_penalty_s=settings.off_track_penalty_s,
            crash_penalty_s=settings.crash_penalty_s, time_limit_s=settings.time_limit_s,
            paced=paced, broadcast_group=broadcast_group[:80], conditions=world or {},
        )  # fmt: skip
        if enqueue:
            enqueue_after_commit(job, dispatch.EVALUATE_RACE)
    return job


def race_conditions_of(job: RaceJob) -> tuple[RaceConfig, RaceSettings]:
    """The bots and settings a stored race job runs with (its cars come from its entries)."""
    race = RaceConfig()
    if job.bots:
        race = RaceConfig.from_dict(race_settings(
            "HEAD_TO_BOT", {"number_of_bots": job.bots, "bot_speed": job.bot_speed}))  # fmt: skip
    settings = RaceSettings(
        laps=job.laps, off_track_penalty_s=job.off_track_penalty_s,
        crash_penalty_s=job.crash_penalty_s, time_limit_s=job.time_limit_s, seed=job.seed,
        round=job.round_number,
    )  # fmt: skip
    return race, settings
