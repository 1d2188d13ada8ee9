"""Models: create, clone, change the reward function, delete; their files in the store.
Imports of uploaded archives are in :mod:`training.services.model_imports`.

Every function is keyword-only and raises :class:`ServiceError` with a message a user can act
on. Creating, cloning and importing are all or nothing (:func:`_all_or_nothing`): the rows are
written in one transaction and the files under the new model's folder; if the store fails
(after its retries) the transaction is rolled back, the folder removed, and the user told that
storage is unavailable and to try again - never a half-made model, never a 500.

Reward functions: the web process runs no user code. How a reward function is checked before
it is saved is the caller's choice (``reward_check``; the rule itself is
:func:`training.services.rewards.reward_check_before_save`):

- ``"passed"`` (the web console): a passed validation of the same source (line endings aside)
  on the same track and direction, by the same user, within the last hour
  (:func:`training.services.rewards.reward_validation_passed`; the Validate button's
  validations count). Parsing errors are answered at once with their lines (parsing runs no
  code); otherwise, without such a pass, nothing is saved and the service returns the
  :class:`~training.services.rewards.RewardCheck` instead of a model: ``needs_validation``
  with the id of the validation it queued on a worker (the page shows its progress and posts
  the same form again once it passes, the form's data kept), or ``refused`` with the errors
  on their lines. A refusal of anything else raises ServiceError, as ever.
- ``"sandbox"`` (the command line, workers): the sandbox runs the function here and now; a
  function it refuses raises RewardRejected (these modes always return a model).
- ``"none"``: no check (imports, whose reward function is never run before training).
"""

from __future__ import annotations

import json
import logging
import random
from collections.abc import Iterator
from contextlib import contextmanager

from django.db import transaction

from training.errors import ServiceError
from training.models import RaceType, RacingModel
from training.services.checks import (
    check_extra_tracks,
    check_model_quota,
    check_model_spec,
    check_name,
)
from training.services.conditions import conditions_check
from training.services.jobs import model_has_active_jobs, owned
from training.services.model_files import (
    TRAINING_PARAMS,
    model_metadata,
    store_failure,
    training_params,
)
from training.services.rewards import RewardCheck, reward_check_before_save
from training.storage import StoreError, StoreUnavailable
from training.store import get_store, keys_for

log = logging.getLogger(__name__)
STORE_UNAVAILABLE = (
    "the model store is unavailable right now, so nothing was saved; try again in a minute"
)


@contextmanager
def _all_or_nothing() -> Iterator[list[int]]:
    """One transaction for the rows; the caller lists the ids of the models it creates, whose
    stored folders are removed if anything fails. A store failure becomes a ServiceError."""
    created: list[int] = []
    try:
        with transaction.atomic():
            yield created
    except BaseException as exc:
        for model_id in created:
            try:
                get_store().delete_prefix(keys_for(model_id).prefix)
            except StoreError:
                log.warning("could not clean up the store of model %s", model_id)
        if isinstance(exc, StoreUnavailable):
            log.warning("store unavailable: %s", exc)
            raise ServiceError(STORE_UNAVAILABLE) from None
        if isinstance(exc, StoreError):
            raise store_failure(exc, "the model's files could not be written") from None
        raise


def _store_model_files(model: RacingModel) -> None:
    store = get_store()
    keys = keys_for(model.pk)
    store.put_bytes(keys.metadata, model_metadata(model).dumps(), "application/json")
    store.put_bytes(
        keys.hyperparameters,
        json.dumps(model.hyperparameters, indent=2).encode(),
        "application/json",
    )
    store.put_bytes(keys.reward_function, model.reward_function.encode(), "text/x-python")
    store.put_bytes(
        f"{keys.prefix}{TRAINING_PARAMS}", training_params(model).encode(), "application/yaml"
    )


def model_create(
    *,
    owner,
    name: str,
    description: str = "",
    track_id: str,
    direction: str = "native",
    race_type: str = RaceType.TIME_TRIAL,
    race_config: dict | None = None,
    sensors: list[str] | tuple[str, ...] = ("FRONT_FACING_CAMERA",),
    action_space: list | dict,
    algorithm: str = "clipped_ppo",
    neural_network: str = "RACECRAFT_LEAN_CNN",
    hyperparameters: dict | None = None,
    reward_function: str,
    max_minutes: int = 10,
    stop_when_ready: int = 0,
    seed: int | None = None,
    validate_reward: bool = True,
    reward_check: str = "sandbox",
    extra_tracks: list | tuple = (),
    conditions: dict | None = None,
) -> RacingModel | RewardCheck:
    """A new model, validated end to end; its reward function is checked on each of its
    tracks as ``reward_check`` says (the module's docstring: ``"passed"`` from the web),
    ``validate_reward=False`` is ``reward_check="none"``. ``extra_tracks``: ``(track_id,
    direction)`` pairs trained on beside ``track_id`` (multi-track training,
    :func:`check_extra_tracks`). ``conditions``: training for the world outside
    (:mod:`training.services.conditions`; None or {}: off). Raises ServiceError or
    RewardRejected; with ``"passed"``, a reward function not saved is answered with its
    :class:`RewardCheck` instead (the first track without a passed validation is being
    validated: the page posts again)."""
    check_name(owner, name)
    if len(description) > 255:
        raise ServiceError("the description is at most 255 characters", field="description")
    check_model_quota(owner)
    spec = check_model_spec(
        track_id=track_id, direction=direction, race_type=race_type, race_config=race_config,
        sensors=list(sensors), action_space=action_space, algorithm=algorithm,
        neural_network=neural_network, hyperparameters=hyperparameters, max_minutes=max_minutes,
        stop_when_ready=stop_when_ready,
    )  # fmt: skip
    extra = check_extra_tracks(track_id, direction, extra_tracks)
    world = conditions_check(conditions)
    how = reward_check if validate_reward else "none"
    tracks = [(spec.track_id, spec.direction), *((t, d) for t, d in extra)]
    check = reward_check_before_save(user=owner, source=reward_function, tracks=tracks, how=how)
    if (not_saved := _not_saved(check, how)) is not None:
        return not_saved
    with _all_or_nothing() as created:
        model = _create_row(owner, name, description, spec, reward_function, seed, extra, world)
        created.append(model.pk)
        _store_model_files(model)
    return model


def _not_saved(check: RewardCheck, how: str) -> RewardCheck | None:
    """None when the reward function may be saved; else the check, the web's answer
    (``"passed"``); the command line and workers get a refusal raised, as ever."""
    if check.is_ready:
        return None
    if how != "passed" and check.error is not None:
        raise check.error
    return check


def _create_row(
    owner, name, description, spec, reward_function, seed, extra, conditions
) -> RacingModel:
    return RacingModel.objects.create(
        owner=owner,
        name=name,
        description=description,
        track_id=spec.track_id,
        direction=spec.direction,
        extra_tracks=extra,
        race_type=spec.race_type,
        race_config=spec.race_config,
        sensors=list(spec.metadata.sensor),
        neural_network=spec.metadata.neural_network,
        action_space_type=spec.metadata.action_space_type,
        action_space=spec.metadata.actions.to_metadata(),
        algorithm=spec.metadata.training_algorithm,
        hyperparameters=spec.hyperparameters,
        reward_function=reward_function,
        max_minutes=spec.max_minutes,
        stop_when_ready=spec.stop_when_ready,
        seed=seed if seed is not None else random.randrange(2**31),
        conditions=conditions,
        status=RacingModel.Status.READY,
    )


def model_clone(
    *,
    model: RacingModel,
    owner,
    name: str,
    description: str = "",
    track_id: str | None = None,
    direction: str | None = None,
    reward_function: str | None = None,
    hyperparameters: dict | None = None,
    max_minutes: int | None = None,
    stop_when_ready: int | None = None,
    action_space: list | dict | None = None,
    checkpoint: str = "best",
    reward_check: str = "sandbox",
    conditions: dict | None = None,
) -> RacingModel | RewardCheck:
    """A new model that starts from ``model``'s best (or last) checkpoint. Algorithm, network,
    sensors, action-space type and number of actions stay as they were; the outside-world
    setting too, unless ``conditions`` is given ({}: off).

    A model without a checkpoint (never trained, or failed before its first one) is copied
    as a fresh model: the same configuration, trained from scratch, with no parent. The reward
    function is checked on the clone's track as ``reward_check`` says (see model_create: with
    ``"passed"``, the :class:`RewardCheck` of a reward function not saved is the answer)."""
    owned(model, owner)
    if checkpoint not in ("best", "last"):
        raise ServiceError("clone from the best or the last checkpoint", field="checkpoint")
    new_actions = model.action_space if action_space is None else action_space
    if model.action_space_type == "discrete" and (
        not isinstance(new_actions, list) or len(new_actions) != len(model.action_space)
    ):
        raise ServiceError(
            "a clone keeps the number of actions; you may change their values",
            field="action_space",
        )
    if model.action_space_type == "continuous" and not isinstance(new_actions, dict):
        raise ServiceError("a clone keeps a continuous action space", field="action_space")
    new_primary = (track_id or model.track_id, direction or model.direction)
    with _all_or_nothing() as created:
        clone = model_create(
            owner=owner,
            name=name,
            description=description,
            track_id=new_primary[0],
            direction=new_primary[1],
            extra_tracks=[pair for pair in model.extra_tracks if tuple(pair) != new_primary],
            race_type=model.race_type,
            race_config=dict(model.race_config or {}),
            sensors=list(model.sensors),
            action_space=new_actions,
            algorithm=model.algorithm,
            neural_network=model.neural_network,
            hyperparameters=(
                hyperparameters if hyperparameters is not None else model.hyperparameters
            ),
            reward_function=(
                reward_function if reward_function is not None else model.reward_function
            ),
            max_minutes=max_minutes or model.max_minutes,
            stop_when_ready=(model.stop_when_ready if stop_when_ready is None else stop_when_ready),
            reward_check=reward_check,
            conditions=dict(model.conditions or {}) if conditions is None else conditions,
        )
        if isinstance(clone, RewardCheck):
            return clone  # nothing written: the reward function waits for its validation
        created.append(clone.pk)
        if not model.has_checkpoint:
            return clone  # a fresh copy: nothing to start from
        store = get_store()
        src, dst = keys_for(model.pk), keys_for(clone.pk)
        try:
            data = store.get_bytes(src.best if checkpoint == "best" else src.last)
        except StoreUnavailable:
            raise
        except StoreError as exc:
            raise store_failure(exc, "the parent's checkpoint could not be copied") from None
        store.put_bytes(dst.checkpoint("initial"), data)
        store.put_bytes(dst.best, data)
        store.put_bytes(dst.last, data)
        clone.parent = model
        clone.has_checkpoint = True
        clone.save(update_fields=["parent", "has_checkpoint", "updated_at"])
    return clone


def model_update_reward(
    *, model: RacingModel, user, reward_function: str, reward_check: str = "sandbox"
) -> RacingModel | RewardCheck:
    """Change the reward function of a model that has never trained (as on DeepRacer, a
    model's configuration is fixed once training starts: clone it to change it); checked as
    ``reward_check`` says (see model_create: with ``"passed"``, the :class:`RewardCheck` of a
    reward function not saved is the answer)."""
    owned(model, user)
    if model.has_checkpoint or model.training_jobs.exists() or model.is_busy:
        raise ServiceError(
            "the reward function is fixed once training has started; clone the model to change it"
        )
    check = reward_check_before_save(user=user, source=reward_function,
                                     tracks=[(model.track_id, model.direction)],
                                     how=reward_check)  # fmt: skip
    if (not_saved := _not_saved(check, reward_check)) is not None:
        return not_saved
    model.reward_function = reward_function
    model.save(update_fields=["reward_function", "updated_at"])
    get_store().put_bytes(
        keys_for(model.pk).reward_function, reward_function.encode(), "text/x-python"
    )
    return model


def model_delete(*, model: RacingModel, user) -> None:
    """Delete a model, its jobs and every stored object. Refused while a job runs."""
    owned(model, user)
    if model_has_active_jobs(model):
        raise ServiceError("stop the model's training or evaluation before deleting it")
    model.status = RacingModel.Status.DELETING
    model.save(update_fields=["status", "updated_at"])
    try:
        get_store().delete_prefix(keys_for(model.pk).prefix)
    except StoreError as exc:
        refusal = store_failure(exc, "the model's files could not be deleted")
        model.status = RacingModel.Status.ERROR
        model.error = refusal.message
        model.save(update_fields=["status", "error", "updated_at"])
        raise refusal from None
    model.delete()
