"""Importing a model from an uploaded archive (Racecraft's virtual model or a DeepRacer
model): the archive read in a bounded child process, its environment taken from its
``training_params.yaml``, the model written all or nothing (:mod:`training.services.models`).
"""

from __future__ import annotations

from training.errors import ServiceError
from training.interchange.archive import ArchiveError, ImportedModel, ImportLimits
from training.interchange.bounded import import_upload
from training.interchange.deepracer import ImportedDeepRacerModel
from training.models import RacingModel
from training.rewards.examples import DEFAULT_EXAMPLE, example_source
from training.rl.hyperparams import defaults_for
from training.services.checks import (
    MAX_READY_STREAK,
    MAX_TRAINING_TRACKS,
    check_extra_tracks,
    check_model_quota,
    check_name,
    check_track,
    track_catalog,
)
from training.services.conditions import PARAMS_KEY as CONDITIONS_KEY
from training.services.conditions import conditions_from_param
from training.services.models import _all_or_nothing, model_create
from training.services.trackfiles import tracks_sync
from training.store import get_store, keys_for


def model_import(*, owner, name: str, upload, description: str = "") -> RacingModel:
    """A model from an uploaded archive: Racecraft's virtual model, or a DeepRacer model (the
    car's archive, the AWS console's virtual model, a DeepRacer-for-Cloud model folder),
    validated; its weights become a Racecraft checkpoint without unpickling anything. Its
    track, direction, seed, stop condition and outside-world setting come from the archive's
    ``training_params.yaml`` when it has one; ``model.import_note`` says what could not be
    kept (an unknown track)."""
    check_name(owner, name)
    check_model_quota(owner)
    tracks_sync()  # the archive's WORLD_NAME may be a track imported on another machine
    imported, source_note = _read_model_upload(upload)
    meta = imported.metadata
    params = read_training_params(imported.extra_files)
    track_id, direction, seed, minutes, note = _imported_environment(params)
    try:
        check_track(track_id, direction)
    except ServiceError:
        direction = "native"
    extra_tracks = _imported_extra_tracks(params, track_id, direction)
    with _all_or_nothing() as created:
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
            stop_when_ready=_imported_stop_when_ready(params),
            validate_reward=False,
            extra_tracks=extra_tracks,
            conditions=conditions_from_param(params.get(CONDITIONS_KEY, "")),
        )
        created.append(model.pk)
        model.import_note = note  # for the caller to show; not stored
        store, keys = get_store(), keys_for(model.pk)
        for key in (keys.best, keys.last, keys.checkpoint("initial")):
            store.put_bytes(key, imported.checkpoint_bytes)
        model.imported = True
        model.has_checkpoint = True
        model.save(update_fields=["imported", "has_checkpoint", "updated_at"])
    return model


class ArchiveRefused(ServiceError):
    """An upload that cannot be imported. Its message often starts with the file at fault
    (``agent/model.pb: ...``), whose name keeps its case in the sentence."""

    @property
    def sentence(self) -> str:
        first = self.message.split(" ", 1)[0].rstrip(":")
        if any(mark in first for mark in "/._"):  # a file name, not a word
            return self.message
        return super().sentence


def _read_model_upload(upload) -> tuple[ImportedModel | ImportedDeepRacerModel, str]:
    """The upload as Racecraft's virtual model, else as a DeepRacer model (it has a frozen
    graph or TensorFlow checkpoints), and a note for the model's description. Read and
    converted in a bounded child process (:mod:`training.interchange.bounded`: memory, CPU
    and time limits; its memory goes back to the system when it ends); only the result comes
    back here. Raises :class:`ArchiveRefused` with the reason."""
    limits = ImportLimits()
    data = upload if isinstance(upload, bytes) else upload.read(limits.max_upload_bytes + 1)
    try:
        imported = import_upload(data, limits=limits)
    except ArchiveError as exc:
        raise ArchiveRefused(str(exc), field="archive") from None
    if not isinstance(imported, ImportedDeepRacerModel):
        return imported, ""
    note = f"Imported from DeepRacer's {imported.source}."
    if imported.value_head_fresh:
        note += " The policy is DeepRacer's; training it further starts the value function fresh."
    return imported, note[:255]


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
    direction = (
        params.get("RACECRAFT_DIRECTION")
        or _droa_direction(params.get("TRACK_DIRECTION_CLOCKWISE", ""))
        or ("cw" if params.get("REVERSE_DIR", "").lower() == "true" else "native")
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


def _imported_stop_when_ready(params: dict[str, str]) -> int:
    """An archive's ``RACECRAFT_STOP_WHEN_READY`` (0, the time limit alone, when absent or
    out of range)."""
    value = params.get("RACECRAFT_STOP_WHEN_READY", "")
    return int(value) if value.isdigit() and int(value) <= MAX_READY_STREAK else 0


def _droa_direction(clockwise: str) -> str:
    """DeepRacer-on-AWS's ``TRACK_DIRECTION_CLOCKWISE`` as a direction ("" when absent)."""
    value = clockwise.lower()
    return "cw" if value == "true" else "ccw" if value == "false" else ""


def _imported_extra_tracks(params: dict[str, str], track_id: str, direction: str) -> list:
    """The tracks a multi-track model was trained on beside ``track_id`` (its
    ``RACECRAFT_TRACKS``), those installed here and valid; anything else is left out."""
    extra = []
    for item in params.get("RACECRAFT_TRACKS", "").split(",")[:MAX_TRAINING_TRACKS]:
        track, _, track_direction = item.strip().partition(":")
        pair = [track, track_direction or "native"]
        if track and tuple(pair) != (track_id, direction):
            try:
                check_extra_tracks(track_id, direction, [*extra, pair])
            except ServiceError:
                continue
            extra.append(pair)
    return extra


def _default_track() -> str:
    ids = track_catalog().ids()
    return "racecraft_summit" if "racecraft_summit" in ids else ids[0]
