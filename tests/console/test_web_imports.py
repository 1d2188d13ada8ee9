"""The web reads training's public face: training.catalog re-exports what the forms offer (the
very objects, one source of truth), and settings load the bucket check without the minio SDK or
the sandbox."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from training import catalog, errors
from training.interchange.archive import ImportLimits
from training.rewards import examples
from training.rl import hyperparams, policies, presets
from training.storage import ObjectNotFound, StoreError

ROOT = Path(__file__).resolve().parents[2]


def test_the_catalog_is_the_internals_own_objects():
    assert catalog.PRESETS is presets.PRESETS and catalog.preset is presets.preset
    assert catalog.RANGES is hyperparams.RANGES
    assert catalog.parse_hyperparameters is hyperparams.parse_hyperparameters
    assert catalog.NETWORK_LABELS is policies.NETWORK_LABELS
    assert catalog.EXAMPLES is examples.EXAMPLES
    assert ImportLimits().max_upload_bytes == catalog.MAX_IMPORT_BYTES
    assert errors.StoreError is StoreError and errors.ObjectNotFound is ObjectNotFound


def test_settings_load_without_the_minio_sdk_or_the_sandbox(tmp_path):
    probe = (
        "import sys; import console.settings as s; assert s.MINIO_BUCKET; "
        "print(sorted(m for m in ('minio', 'training.sandbox') if m in sys.modules))"
    )
    env = {**os.environ, "RACECRAFT_VAR_DIR": str(tmp_path)}
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
