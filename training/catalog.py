"""What the web offers and labels, read from where each thing is defined (one source of truth):
the create form's presets and hyperparameter specs, DeepRacer's example reward functions, the
networks' labels, the limits on a reward's source and on an imported archive.

The console and the league import training through this module, ``services``, ``selectors``,
``models`` and small helpers such as ``formatting``, never training's internals (``rl``,
``rollout``, ``sandbox``, ``interchange``, ``storage``, ``rewards``, ``analysis``,
``worker``): an import-linter contract in pyproject.toml holds that line.
"""

from __future__ import annotations

from training.interchange.archive import ImportLimits
from training.rewards.examples import EXAMPLES, example_source
from training.rl.hyperparams import (
    BATCH_SIZES,
    LOSS_TYPES,
    RANGES,
    SAC_DEFAULTS,
    HyperparameterError,
    Hyperparameters,
    parse_hyperparameters,
)
from training.rl.policies import LEAN, NETWORK_LABELS
from training.rl.presets import DEFAULT_PRESET, PRESETS, Preset, UnknownPreset, preset
from training.sandbox import MAX_SOURCE_CHARS

MAX_IMPORT_BYTES = ImportLimits().max_upload_bytes
"""The largest model archive an import takes, bytes (the upload itself, before unpacking)."""

__all__ = [
    "BATCH_SIZES",
    "DEFAULT_PRESET",
    "EXAMPLES",
    "LEAN",
    "LOSS_TYPES",
    "MAX_IMPORT_BYTES",
    "MAX_SOURCE_CHARS",
    "NETWORK_LABELS",
    "PRESETS",
    "RANGES",
    "SAC_DEFAULTS",
    "HyperparameterError",
    "Hyperparameters",
    "Preset",
    "UnknownPreset",
    "example_source",
    "parse_hyperparameters",
    "preset",
]
