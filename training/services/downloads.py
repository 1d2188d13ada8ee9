"""What a user downloads: the car model, the virtual model, the logs, evaluation videos."""

from __future__ import annotations

from collections.abc import Callable

from training.errors import ServiceError
from training.http import Media
from training.interchange.carmodel import CarExportError, build_car_archive
from training.interchange.coachexport import download_refusal
from training.interchange.export import (
    build_logs_archive,
    build_virtual_model_archive,
    export_onnx,
)
from training.interchange.layout import RaceKeys, evaluation_stamp
from training.models import EvaluationJob, RaceJob, RacingModel
from training.rl.checkpoints import CheckpointError, load_checkpoint
from training.rl.metadata import MetadataError
from training.services.model_files import (
    TRAINING_PARAMS,
    model_metadata,
    store_failure,
    training_params,
)
from training.storage import ObjectNotFound, StoreError, StoreUnavailable
from training.store import get_store, keys_for


def _need_checkpoint(model: RacingModel) -> None:
    if not model.has_checkpoint:
        raise ServiceError("this model has no trained checkpoint yet")


def car_model_archive(model: RacingModel) -> bytes:
    """``physicalmodel-<name>.tar.gz`` for the physical car: ``agent/model.pb`` (a frozen TensorFlow
    graph with DeepRacer's names) and ``model_metadata.json`` at its root. The archive kept in
    the store when there is one, else built now (:func:`car_archive_build`)."""
    _need_checkpoint(model)
    stored = car_archive_stored(model)
    return stored if stored is not None else car_archive_build(model)


def car_archive_stored(model: RacingModel) -> bytes | None:
    """The car archive already built into the store (a store read, nothing heavy), else None.
    An unreachable store is raised as it is (the page answers 503 "try again":
    console/middleware.py); another store failure as a ServiceError."""
    try:
        return get_store().get_bytes(keys_for(model.pk).car_export)
    except ObjectNotFound:
        return None
    except StoreUnavailable:
        raise
    except StoreError as exc:
        raise store_failure(exc, "the car model could not be read") from None


def car_archive_build(model: RacingModel) -> bytes:
    """Build the car archive from the model's best checkpoint and keep it in the store, over
    any earlier one: the one way a car archive is made (the download, the background export
    and the export after training all come here; the bytes are
    :func:`training.interchange.carmodel.build_car_archive`'s). Raises ServiceError, or
    StoreUnavailable as it is."""
    try:
        data = build_car_archive(model_metadata(model), _best_checkpoint(model))
    except (CarExportError, CheckpointError) as exc:
        raise ServiceError(f"this model cannot be written for the car: {exc}") from None
    try:
        get_store().put_bytes(keys_for(model.pk).car_export, data, "application/gzip")
    except StoreUnavailable:
        raise
    except StoreError as exc:
        raise store_failure(exc, "the car model could not be saved") from None
    return data


def onnx_policy(model: RacingModel) -> bytes:
    """``<name>-policy.onnx``: the policy as ONNX for other runtimes (not for the car)."""
    _need_checkpoint(model)
    metadata = model_metadata(model)
    try:
        return export_onnx(load_checkpoint(_best_checkpoint(model), metadata), metadata)
    except CheckpointError as exc:
        raise ServiceError(f"the model's checkpoint could not be read: {exc}") from None


def _best_checkpoint(model: RacingModel) -> bytes:
    try:
        return get_store().get_bytes(keys_for(model.pk).best)
    except StoreError as exc:
        raise store_failure(exc, "the model's checkpoint could not be read") from None


def _collect(model: RacingModel, keep: Callable[[str], bool], what: str) -> dict[str, bytes]:
    """The model's stored files whose name (inside its folder) ``keep`` accepts."""
    store, prefix = get_store(), keys_for(model.pk).prefix
    try:
        return {
            key[len(prefix) :]: store.get_bytes(key)
            for key in store.list(prefix)
            if keep(key[len(prefix) :])
        }
    except StoreError as exc:
        raise store_failure(exc, f"the model's {what} could not be read") from None


def _in_virtual_model(name: str) -> bool:
    if name == "model/initial.zip":  # where a clone started: not part of the model
        return False
    return name.startswith(("model/", "ip/", "metrics/TrainingMetrics")) or name == (
        "reward_function.py"
    )


_LOG_FOLDERS = ("training-simtrace/", "evaluation-", "evaluation/")
"""Sim-trace folders: DeepRacer-for-Cloud's, and ``evaluation/<id>/`` of older evaluations."""


def _in_logs(name: str) -> bool:
    return name.startswith((*_LOG_FOLDERS, "metrics/")) or name in (
        "reward_function.py",
        "model/model_metadata.json",
        "ip/hyperparameters.json",
    )


def virtual_model_archive(model: RacingModel) -> bytes:
    """``virtualmodel-<name>.tar.gz``, the whole model (re-importable here, and laid out as
    DeepRacer-on-AWS exports one): metadata, hyperparameters, training parameters, reward,
    checkpoints (:func:`training.interchange.export.build_virtual_model_archive`). A model
    stored before its training parameters were gets them written now."""
    _need_checkpoint(model)
    files = _collect(model, _in_virtual_model, "files")
    files.setdefault(TRAINING_PARAMS, training_params(model).encode())
    return build_virtual_model_archive(files)


def deepracer_on_aws_refusal(model: RacingModel) -> str | None:
    """Why DeepRacer-on-AWS's validation would refuse this model's virtual-model download (it
    then holds no DeepRacer checkpoint), or None when the download holds one."""
    try:
        return download_refusal(model_metadata(model))
    except MetadataError as exc:
        return f"its model_metadata.json cannot be written ({exc})"


def logs_archive(model: RacingModel) -> bytes:
    """Sim-traces, metrics, metadata and hyperparameters in the DeepRacer console's logs
    layout under the model's folder name (:mod:`training.interchange.logarchive`):
    ``deepracer-utils`` reads the download as it is (``TarFileHandler``) or extracted
    (``DeepRacerLog("<folder>")``). The training sim-traces' run folder is named after the
    model's creation, ``training-<YYYYMMDDhhmmss>``."""
    files = _collect(model, _in_logs, "logs")
    if not any(n.startswith(_LOG_FOLDERS) for n in files):
        raise ServiceError("there are no logs yet: train or evaluate the model first")
    return build_logs_archive(
        files,
        folder=model.store_folder,
        training_run=f"training-{evaluation_stamp(model.created_at)}",
    )


def evaluation_video(evaluation: EvaluationJob) -> Media:
    """The evaluation's MP4 as ranged reads from the store (never loaded whole)."""
    if not evaluation.has_video:
        raise ServiceError("this evaluation has no video")
    store, key = get_store(), keys_for(evaluation.model_id).video(evaluation.pk)
    try:
        size = store.stat_size(key)
    except StoreError as exc:
        raise store_failure(exc, "the video could not be read") from None
    return Media(size, lambda start, length: store.get_range(key, start, length))


def race_video(race: RaceJob) -> Media | None:
    """A race's broadcast MP4 as ranged reads from the store; None when it has none."""
    if not race.has_video:
        return None
    store, key = get_store(), RaceKeys(race.pk).video
    try:
        size = store.stat_size(key)
    except StoreError as exc:
        raise store_failure(exc, "the video could not be read") from None
    return Media(size, lambda start, length: store.get_range(key, start, length))
