"""What a model's folder in the store says about it besides its weights: DeepRacer's
``model_metadata.json`` and ``training_params.yaml`` (:func:`model_metadata`,
:func:`training_params`); and :func:`store_failure`, a failure of the store as a user reads it.
"""

from __future__ import annotations

import logging

from training.errors import ServiceError
from training.interchange.layout import RaceKeys
from training.models import RacingModel
from training.rl.metadata import ModelMetadata, build_metadata
from training.services.conditions import PARAMS_KEY as CONDITIONS_KEY
from training.services.conditions import conditions_param
from training.storage import StoreError, StoreUnavailable
from training.store import get_store, keys_for

log = logging.getLogger(__name__)


def store_failure(exc: StoreError, what: str) -> ServiceError:
    """A store failure as a user may read it: what could not be done, never the object key,
    the store's folder or endpoint, nor the store's own words (those go to the log)."""
    log.warning("store failure (%s): %s", what, exc)
    if isinstance(exc, StoreUnavailable):
        return ServiceError(f"{what}: the model store is unavailable now; try again in a minute")
    return ServiceError(
        f"{what}: the model store refused it; try again, and if it keeps failing tell the "
        "administrator (the server's log says why)"
    )


#: Where the training environment is written, inside the model's folder: under ``ip/`` so the
#: virtual-model download carries it and an import reads it back (DeepRacer keeps the same
#: facts in ``training_params.yaml``).
TRAINING_PARAMS = "ip/training_params.yaml"


def training_params(model: RacingModel) -> str:
    """DeepRacer's ``training_params.yaml`` keys for the model's environment, plus ours
    (``RACECRAFT_*``, which DeepRacer's tools ignore; the outside-world setting as JSON)."""
    lines = {
        "WORLD_NAME": model.track_id,
        "RACE_TYPE": model.race_type,
        "REVERSE_DIR": "true" if model.direction == "cw" else "false",
        "RACECRAFT_DIRECTION": model.direction,
        "RACECRAFT_SEED": str(model.seed),
        "RACECRAFT_MAX_MINUTES": str(model.max_minutes),
        "RACECRAFT_STOP_WHEN_READY": str(model.stop_when_ready),
    }
    if model.extra_tracks:  # multi-track training: every track:direction the cars are dealt
        lines["RACECRAFT_TRACKS"] = ",".join(f"{t}:{d}" for t, d in model.training_tracks)
    text = "".join(f'{key}: "{value}"\n' for key, value in lines.items())
    if conditions := conditions_param(model.conditions):  # one line of JSON, single-quoted
        text += f"{CONDITIONS_KEY}: '{conditions}'\n"
    return text


def model_metadata(model: RacingModel) -> ModelMetadata:
    """DeepRacer's ``model_metadata.json`` for the model."""
    return build_metadata(
        action_space=model.action_space,
        training_algorithm=model.algorithm,
        sensor=list(model.sensors),
        neural_network=model.neural_network,
    )


def model_freeze(*, model: RacingModel, scope: str, entry: int) -> str:
    """Copy the model's best checkpoint to ``league/<scope>/<entry>.zip`` in the store (a
    league entry's weights, which later training or deleting the model does not touch);
    returns that key. Raises the store's errors."""
    key = RaceKeys.frozen_checkpoint(scope, entry)
    store = get_store()
    store.put_bytes(key, store.get_bytes(keys_for(model.pk).best))
    return key
