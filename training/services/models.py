"""Models: create, clone, import, delete; their files in the store.

Every function is keyword-only and raises :class:`ServiceError` with a message a user can act
on; a model whose files could not be written is removed again (no half-made rows).
"""

from __future__ import annotations

import json
import logging
import random

from training.errors import ServiceError
from training.interchange.archive import (
    ArchiveError,
    ImportedModel,
    import_virtual_model,
    read_archive,
)
from training.interchange.deepracer import ImportedDeepRacerModel, import_deepracer_upload
from training.models import RaceType, RacingModel
from training.rewards.examples import DEFAULT_EXAMPLE, example_source
from training.rl.hyperparams import defaults_for
from training.rl.metadata import ModelMetadata, build_metadata
from training.services.checks import (
    check_model_quota,
    check_model_spec,
    check_name,
    check_reward,
    check_track,
    track_catalog,
)
from training.services.jobs import model_has_active_jobs, owned
from training.storage import StoreError
from training.store import get_store, keys_for

log = logging.getLogger(__name__)


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


#: Where the training environment is written, inside the model's folder: under ``ip/`` so the
#: virtual-model download carries it and an import reads it back (DeepRacer keeps the same
#: facts in ``training_params.yaml``).
TRAINING_PARAMS = "ip/training_params.yaml"


def training_params(model: RacingModel) -> str:
    """DeepRacer's ``training_params.yaml`` keys for the model's environment, plus ours."""
    lines = {
        "WORLD_NAME": model.track_id,
        "RACE_TYPE": model.race_type,
        "REVERSE_DIR": "true" if model.direction == "cw" else "false",
        "RACECRAFT_DIRECTION": model.direction,
        "RACECRAFT_SEED": str(model.seed),
        "RACECRAFT_MAX_MINUTES": str(model.max_minutes),
    }
    return "".join(f'{key}: "{value}"\n' for key, value in lines.items())


def read_training_params(files: dict[str, bytes]) -> dict[str, str]:
    """The flat ``KEY: value`` pairs of an archive's ``training_params.yaml`` (in any folder;
    a yaml library is not needed for DeepRacer's flat file). Empty when there is none."""
    name = next((n for n in sorted(files) if n.rsplit("/", 1)[-1] == "training_params.yaml"), None)
    if name is None:
        return {}
    try:
        text = files[name].decode("utf-8-sig")
    except UnicodeDecodeError:
        return {}
    params: dict[str, str] = {}
    for line in text.splitlines()[:500]:
        key, sep, value = line.partition(":")
        if sep and key.strip() and not key.startswith((" ", "#", "-")):
            params[key.strip()] = value.split(" #")[0].strip().strip("'\"")
    return params


def _imported_environment(params: dict[str, str]) -> tuple[str, str, int | None, int, str]:
    """``(track_id, direction, seed, max_minutes, note)`` from an archive's training params;
    the note says what could not be kept."""
    ids = track_catalog().ids()
    world = params.get("WORLD_NAME", "")
    note = ""
    if world in ids:
        track_id = world
    else:
        track_id = _default_track()
        note = (
            f"the archive was trained on {world!r}, which is not installed here; it uses "
            f"{track_id} (import the track, then clone the model onto it)"
            if world
            else f"the archive does not name its track; it uses {track_id}"
        )
    direction = params.get("RACECRAFT_DIRECTION") or (
        "cw" if params.get("REVERSE_DIR", "").lower() == "true" else "native"
    )
    if direction not in ("native", "ccw", "cw"):
        direction = "native"
    seed = params.get("RACECRAFT_SEED", "")
    minutes = params.get("RACECRAFT_MAX_MINUTES", "")
    return (
        track_id,
        direction,
        int(seed) if seed.isdigit() and int(seed) < 2**31 else None,
        int(minutes) if minutes.isdigit() and 1 <= int(minutes) <= 1440 else 10,
        note,
    )


def model_metadata(model: RacingModel) -> ModelMetadata:
    """DeepRacer's ``model_metadata.json`` for the model."""
    return build_metadata(
        action_space=model.action_space,
        training_algorithm=model.algorithm,
        sensor=list(model.sensors),
        neural_network=model.neural_network,
    )


def model_create(
    *,
    owner,
    name: str,
    description: str = "",
    track_id: str,
    direction: str = "native",
    race_type: str = RaceType.TIME_TRIAL,
    sensors: list[str] | tuple[str, ...] = ("FRONT_FACING_CAMERA",),
    action_space: list | dict,
    algorithm: str = "clipped_ppo",
    neural_network: str = "RACECRAFT_LEAN_CNN",
    hyperparameters: dict | None = None,
    reward_function: str,
    max_minutes: int = 10,
    seed: int | None = None,
    validate_reward: bool = True,
) -> RacingModel:
    """A new model, validated end to end (its reward function runs in the sandbox first)."""
    check_name(owner, name)
    if len(description) > 255:
        raise ServiceError("the description is at most 255 characters", field="description")
    check_model_quota(owner)
    spec = check_model_spec(
        track_id=track_id, direction=direction, race_type=race_type, sensors=list(sensors),
        action_space=action_space, algorithm=algorithm, neural_network=neural_network,
        hyperparameters=hyperparameters, max_minutes=max_minutes,
    )  # fmt: skip
    if validate_reward:
        check_reward(reward_function, track_id, direction)
    model = RacingModel.objects.create(
        owner=owner,
        name=name,
        description=description,
        track_id=spec.track_id,
        direction=spec.direction,
        race_type=spec.race_type,
        sensors=list(spec.metadata.sensor),
        neural_network=spec.metadata.neural_network,
        action_space_type=spec.metadata.action_space_type,
        action_space=spec.metadata.actions.to_metadata(),
        algorithm=spec.metadata.training_algorithm,
        hyperparameters=spec.hyperparameters,
        reward_function=reward_function,
        max_minutes=spec.max_minutes,
        seed=seed if seed is not None else random.randrange(2**31),
        status=RacingModel.Status.READY,
    )
    _store_model_files(model)
    return model


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
    action_space: list | dict | None = None,
    checkpoint: str = "best",
) -> RacingModel:
    """A new model that starts from ``model``'s best (or last) checkpoint. Algorithm, network,
    sensors, action-space type and number of actions stay as they were.

    A model without a checkpoint (never trained, or failed before its first one) is copied
    as a fresh model: the same configuration, trained from scratch, with no parent."""
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
    clone = model_create(
        owner=owner,
        name=name,
        description=description,
        track_id=track_id or model.track_id,
        direction=direction or model.direction,
        race_type=model.race_type,
        sensors=list(model.sensors),
        action_space=new_actions,
        algorithm=model.algorithm,
        neural_network=model.neural_network,
        hyperparameters=hyperparameters if hyperparameters is not None else model.hyperparameters,
        reward_function=reward_function if reward_function is not None else model.reward_function,
        max_minutes=max_minutes or model.max_minutes,
        validate_reward=True,
    )
    if not model.has_checkpoint:
        return clone  # a fresh copy: nothing to start from
    store = get_store()
    src, dst = keys_for(model.pk), keys_for(clone.pk)
    try:
        data = store.get_bytes(src.best if checkpoint == "best" else src.last)
        store.put_bytes(dst.checkpoint("initial"), data)
        store.put_bytes(dst.best, data)
        store.put_bytes(dst.last, data)
    except StoreError as exc:
        _delete_quietly(clone)
        raise ServiceError(f"the parent's checkpoint could not be copied: {exc}") from None
    clone.parent = model
    clone.has_checkpoint = True
    clone.save(update_fields=["parent", "has_checkpoint", "updated_at"])
    return clone


def model_update_reward(*, model: RacingModel, user, reward_function: str) -> RacingModel:
    """Change the reward function of a model that has never trained (as on DeepRacer, a
    model's configuration is fixed once training starts: clone it to change it)."""
    owned(model, user)
    if model.has_checkpoint or model.training_jobs.exists() or model.is_busy:
        raise ServiceError(
            "the reward function is fixed once training has started; clone the model to change it"
        )
    check_reward(reward_function, model.track_id, model.direction)
    model.reward_function = reward_function
    model.save(update_fields=["reward_function", "updated_at"])
    get_store().put_bytes(
        keys_for(model.pk).reward_function, reward_function.encode(), "text/x-python"
    )
    return model


def _delete_quietly(model: RacingModel) -> None:
    """Undo a model whose files could not be completed."""
    try:
        get_store().delete_prefix(keys_for(model.pk).prefix)
    except StoreError:
        log.warning("could not clean up the store of model %s", model.pk)
    model.delete()


def model_import(*, owner, name: str, upload, description: str = "") -> RacingModel:
    """A model from an uploaded archive: Racecraft's virtual model, or a DeepRacer model (the
    car's archive, the AWS console's virtual model, a DeepRacer-for-Cloud model folder),
    validated; its weights become a Racecraft checkpoint without unpickling anything. Its
    track, direction, seed and stop condition come from the archive's ``training_params.yaml``
    when it has one; ``model.import_note`` says what could not be kept (an unknown track)."""
    check_name(owner, name)
    check_model_quota(owner)
    imported, source_note = _read_model_upload(upload)
    meta = imported.metadata
    track_id, direction, seed, minutes, note = _imported_environment(
        read_training_params(imported.extra_files)
    )
    try:
        check_track(track_id, direction)
    except ServiceError:
        direction = "native"
    model = model_create(
        owner=owner,
        name=name,
        description=description or source_note,
        track_id=track_id,
        direction=direction,
        seed=seed,
        sensors=list(meta.sensor),
        action_space=meta.actions.to_metadata(),
        algorithm=meta.training_algorithm,
        neural_network=meta.neural_network,
        hyperparameters=(
            imported.hyperparameters or defaults_for(meta.training_algorithm)
        ).to_json(),
        reward_function=imported.reward_function or example_source(DEFAULT_EXAMPLE),
        max_minutes=minutes,
        validate_reward=False,
    )
    model.import_note = note  # for the caller to show; not stored
    store, keys = get_store(), keys_for(model.pk)
    for key in (keys.best, keys.last, keys.checkpoint("initial")):
        store.put_bytes(key, imported.checkpoint_bytes)
    model.imported = True
    model.has_checkpoint = True
    model.save(update_fields=["imported", "has_checkpoint", "updated_at"])
    return model


def _read_model_upload(upload) -> tuple[ImportedModel | ImportedDeepRacerModel, str]:
    """The upload as Racecraft's virtual model, else as a DeepRacer model (it has a frozen
    graph or TensorFlow checkpoints), and a note for the model's description."""
    data = upload if isinstance(upload, bytes) else upload.read()
    try:
        return import_virtual_model(data), ""
    except ArchiveError as exc:
        racecraft_error = exc
    try:
        deepracer_files = any(
            n.endswith((".pb", ".ckpt.index", ".index")) for n in read_archive(data)
        )
        if not deepracer_files:
            raise racecraft_error
        imported = import_deepracer_upload(data)
    except ArchiveError as exc:
        raise ServiceError(str(exc), field="archive") from None
    note = f"Imported from DeepRacer's {imported.source}."
    if imported.value_head_fresh:
        note += " The policy is DeepRacer's; training it further starts the value function fresh."
    return imported, note[:255]


def _default_track() -> str:
    ids = track_catalog().ids()
    return "racecraft_summit" if "racecraft_summit" in ids else ids[0]


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
        model.status = RacingModel.Status.ERROR
        model.error = f"deleting the stored files failed: {exc}"
        model.save(update_fields=["status", "error", "updated_at"])
        raise ServiceError(f"the model's files could not be deleted: {exc}") from None
    model.delete()
