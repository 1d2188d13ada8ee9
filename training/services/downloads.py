"""What a user downloads: the car model, the virtual model, the logs, evaluation videos."""

from __future__ import annotations

from training.interchange.export import (
    build_car_archive,
    build_logs_archive,
    build_virtual_model_archive,
)
from training.models import EvaluationJob, RacingModel
from training.services import ServiceError, model_metadata
from training.storage import ObjectNotFound, StoreError
from training.store import get_store, keys_for


def _need_checkpoint(model: RacingModel) -> None:
    if not model.has_checkpoint:
        raise ServiceError("this model has no trained checkpoint yet")


def car_model_archive(model: RacingModel) -> bytes:
    """``<name>-car.tar.gz``: model_metadata.json + model.onnx for the physical car."""
    _need_checkpoint(model)
    store, keys = get_store(), keys_for(model.pk)
    try:
        return store.get_bytes(keys.car_export)
    except ObjectNotFound:
        pass
    from training.interchange.export import export_onnx
    from training.rl.checkpoints import load_checkpoint

    metadata = model_metadata(model)
    try:
        policy = load_checkpoint(store.get_bytes(keys.best), metadata)
    except StoreError as exc:
        raise ServiceError(f"the model's checkpoint could not be read: {exc}") from None
    data = build_car_archive(metadata, export_onnx(policy))
    store.put_bytes(keys.car_export, data, "application/gzip")
    return data


def virtual_model_archive(model: RacingModel) -> bytes:
    """The whole model (re-importable): metadata, hyperparameters, reward, checkpoints."""
    _need_checkpoint(model)
    store, keys = get_store(), keys_for(model.pk)
    prefix = keys.prefix
    files: dict[str, bytes] = {}
    try:
        for key in store.list(prefix):
            name = key[len(prefix) :]
            if name.startswith(("model/", "ip/", "metrics/TrainingMetrics")) or name == (
                "reward_function.py"
            ):
                if name == "model/initial.zip":
                    continue
                files[name] = store.get_bytes(key)
    except StoreError as exc:
        raise ServiceError(f"the model's files could not be read: {exc}") from None
    return build_virtual_model_archive(files)


def logs_archive(model: RacingModel) -> bytes:
    """Sim-traces, metrics and evaluation logs in DeepRacer-for-Cloud's folder layout."""
    store, keys = get_store(), keys_for(model.pk)
    prefix = keys.prefix
    files: dict[str, bytes] = {}
    try:
        for key in store.list(prefix):
            name = key[len(prefix) :]
            if name.startswith(("training-simtrace/", "metrics/", "evaluation/")) or name in (
                "reward_function.py",
                "model/model_metadata.json",
                "ip/hyperparameters.json",
            ):
                files[name] = store.get_bytes(key)
    except StoreError as exc:
        raise ServiceError(f"the model's logs could not be read: {exc}") from None
    if not any(n.startswith(("training-simtrace/", "evaluation/")) for n in files):
        raise ServiceError("there are no logs yet: train or evaluate the model first")
    return build_logs_archive(files)


def evaluation_video(evaluation: EvaluationJob) -> bytes:
    if not evaluation.has_video:
        raise ServiceError("this evaluation has no video")
    try:
        return get_store().get_bytes(keys_for(evaluation.model_id).video(evaluation.pk))
    except StoreError as exc:
        raise ServiceError(f"the video could not be read: {exc}") from None
