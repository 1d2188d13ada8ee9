"""Checks shared by the services: tracks, model configuration, reward functions, names, quotas.

Each raises :class:`~training.errors.ServiceError` naming the form field to show the
message on.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from django.conf import settings

from racing.track import Track, TrackError
from racing.tracks import TrackCatalog, UnknownTrackError
from training.errors import RewardRejected, ServiceError
from training.models import MODEL_NAME_RE, Direction, RacingModel
from training.rewards.validation import validate_reward_function
from training.rl.hyperparams import HyperparameterError, parse_hyperparameters
from training.rl.metadata import MetadataError, ModelMetadata, build_metadata
from training.sandbox.static import source_too_long
from training.services.racing import (  # noqa: F401 - the race rules live in racing
    SUPPORTED_RACE_TYPES,
    check_race_type,
    race_settings,
)

MIN_MINUTES, MAX_MINUTES = 1, 1440
MAX_READY_STREAK = 20
"""The most evaluations in a row a "stop when ready" condition may ask for."""
MAX_TRAINING_TRACKS = 4
"""Tracks one model may train on at once (multi-track training): each gets at least two of a
run's 8 cars."""


def track_catalog() -> TrackCatalog:
    """The built-in tracks and those imported into ``RACECRAFT_TRACKS_DIR``: the one catalogue
    the console, the services and the jobs use."""
    return TrackCatalog([settings.RACECRAFT_TRACKS_DIR])


def limit(name: str, default: int) -> int:
    """An integer limit from settings (``RACECRAFT_MAX_*``)."""
    return int(getattr(settings, name, default))


@dataclass(frozen=True)
class ModelSpec:
    """A validated model configuration."""

    metadata: ModelMetadata
    hyperparameters: dict
    track_id: str
    direction: str
    race_type: str
    max_minutes: int
    race_config: dict = field(default_factory=dict)
    """The race's settings (:func:`training.services.racing.race_settings`); {} in a time
    trial."""
    stop_when_ready: int = 0
    """Evaluations in a row that complete every lap to stop at (0: the time limit alone)."""


def check_track(track_id: str, direction: str) -> Track:
    """The track ``track_id`` driven in ``direction``."""
    try:
        track = track_catalog().load(track_id)
    except (UnknownTrackError, TrackError):
        raise ServiceError(f"unknown track {track_id!r}", field="track_id") from None
    if direction not in Direction.values:
        raise ServiceError("direction must be native, ccw or cw", field="direction")
    if not track.closed and direction != Direction.NATIVE:
        raise ServiceError("this track is an open route: it has one direction", field="direction")
    return track.in_direction(direction)


def check_extra_tracks(track_id: str, direction: str, extra_tracks: object) -> list[list[str]]:
    """The tracks a model trains on beside its own (multi-track training), as stored:
    ``[[track_id, direction], ...]``. Each must be a track the model may drive in that
    direction, none twice (its own included), at most :data:`MAX_TRAINING_TRACKS` in all."""
    if not extra_tracks:
        return []
    if not isinstance(extra_tracks, list | tuple):
        raise ServiceError(
            "the extra tracks are a list of (track, direction)", field="extra_tracks"
        )
    pairs: list[list[str]] = []
    seen = {(track_id, direction)}
    for item in extra_tracks:
        if not isinstance(item, list | tuple) or len(item) != 2:
            raise ServiceError(
                "each extra track is a (track, direction) pair", field="extra_tracks"
            )
        extra, extra_direction = (str(v) for v in item)
        try:
            check_track(extra, extra_direction)
        except ServiceError as exc:
            raise ServiceError(
                f"{exc.message} (extra track {extra})", field="extra_tracks"
            ) from None
        if (extra, extra_direction) in seen:
            raise ServiceError(
                f"{extra} ({extra_direction}) is chosen twice; pick each track once",
                field="extra_tracks",
            )
        seen.add((extra, extra_direction))
        pairs.append([extra, extra_direction])
    if len(seen) > MAX_TRAINING_TRACKS:
        raise ServiceError(
            f"a model trains on at most {MAX_TRAINING_TRACKS} tracks at once; this one has "
            f"{len(seen)}",
            field="extra_tracks",
        )
    return pairs


def check_model_spec(
    *,
    track_id: str,
    direction: str,
    race_type: str,
    sensors: list[str],
    action_space: list | dict,
    algorithm: str,
    neural_network: str,
    hyperparameters: dict | None,
    max_minutes: int,
    race_config: dict | None = None,
    stop_when_ready: int = 0,
) -> ModelSpec:
    """The whole configuration of a new model, checked; raises on the first problem.
    ``race_config`` holds the settings of an object-avoidance or head-to-bot race."""
    check_track(track_id, direction)
    race = race_settings(race_type, race_config)
    try:
        metadata = build_metadata(
            action_space=action_space,
            training_algorithm=algorithm,
            sensor=list(sensors),
            neural_network=neural_network,
        )
    except MetadataError as exc:
        raise ServiceError(exc.message, field=_metadata_field(exc.field)) from None
    try:
        hp = parse_hyperparameters(hyperparameters or {}, algorithm)
    except HyperparameterError as exc:
        raise ServiceError(str(exc), field="hyperparameters") from None
    if not isinstance(max_minutes, int) or not MIN_MINUTES <= max_minutes <= MAX_MINUTES:
        raise ServiceError(
            f"the stop condition is {MIN_MINUTES}-{MAX_MINUTES} minutes", field="max_minutes"
        )
    check_stop_when_ready(stop_when_ready)
    return ModelSpec(metadata, hp.to_json(), track_id, direction, race_type, max_minutes, race,
                     stop_when_ready)  # fmt: skip


def check_stop_when_ready(value: int) -> None:
    """``value`` as a "stop when ready" condition: 0 (off) to :data:`MAX_READY_STREAK`."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_READY_STREAK:
        raise ServiceError(
            f"stop when ready after 1-{MAX_READY_STREAK} evaluations in a row that complete "
            "every lap, or 0 for the time limit alone",
            field="stop_when_ready",
        )


def _metadata_field(field: str) -> str:
    return {
        "training_algorithm": "algorithm",
        "sensor": "sensors",
        "action_space_type": "action_space",
    }.get(field, field)


def check_reward(source: str, track_id: str, direction: str = "native") -> dict:
    """Validate a reward function on the track (static checks, then sandboxed runs)."""
    if not isinstance(source, str) or not source.strip():
        raise ServiceError("write a reward function", field="reward_function")
    if (too_long := source_too_long(source)) is not None:
        raise RewardRejected([too_long])
    track = check_track(track_id, direction)
    result = validate_reward_function(source, track)
    if not result.ok:
        raise RewardRejected(result.errors)
    return {"rewards": result.rewards}


def check_name(owner, name: str, *, exclude: int | None = None) -> None:
    """A valid model name the owner does not use yet."""
    if not isinstance(name, str) or not re.match(MODEL_NAME_RE, name):
        raise ServiceError("a model name is 1-64 letters, digits or hyphens", field="name")
    taken = RacingModel.objects.filter(owner=owner, name=name)
    if exclude is not None:
        taken = taken.exclude(pk=exclude)
    if taken.exists():
        raise ServiceError(f"you already have a model named {name!r}", field="name")


def check_model_quota(owner) -> None:
    """Room for one more model within ``RACECRAFT_MAX_MODELS_PER_USER``."""
    most = limit("RACECRAFT_MAX_MODELS_PER_USER", 50)
    if RacingModel.objects.filter(owner=owner).count() >= most:
        raise ServiceError(f"you have {most} models, the most allowed; delete one to make room")
