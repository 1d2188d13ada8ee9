"""The web reads training's public face: training.catalog re-exports what the forms offer (the
very objects, one source of truth), and settings load the bucket check without the minio SDK or
the sandbox."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

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


# ------------------------------------------------------------------ the bucket form's limits
def _bucket_form(endpoint: str, name: str = "web-drfc") -> dict:
    return {"name": name, "endpoint": endpoint, "bucket": "bucket",
            "prefix": "rl-deepracer-sagemaker", "access_key": "AKIAHOSTILE",
            "secret_key": "s3cr3t"}  # fmt: skip


@pytest.mark.django_db
@pytest.mark.usefixtures("fresh_rate_counts", "store_dir")
def test_bucket_imports_are_rate_limited_per_racer(settings, frozen_clock, alice_client) -> None:
    """Past RACECRAFT_BUCKET_IMPORT_RATE the form answers 429 and reaches no server: every POST
    counts, a refused one too."""
    from tests.training.storage.hostile_bucket import hostile_server

    settings.RACECRAFT_BUCKET_IMPORT_RATE = "2/m"
    settings.RACECRAFT_OUTBOUND_ALLOW = ["127.0.0.1"]
    with hostile_server() as server:
        server.mode = "html"
        codes = [alice_client.post("/models/import/bucket/", _bucket_form(server.endpoint))
                 for _ in range(3)]  # fmt: skip
        assert [r.status_code for r in codes] == [400, 400, 429]
        assert "Too many imports from a bucket" in codes[2].content.decode()
        assert server.counts.requests == 2  # one each for the first two (the region's)
        frozen_clock.advance(60)  # the window has passed
        assert alice_client.post("/models/import/bucket/", _bucket_form(server.endpoint)
                                 ).status_code == 400  # fmt: skip
        assert server.counts.requests == 3


@pytest.mark.django_db
@pytest.mark.usefixtures("fresh_rate_counts", "store_dir")
def test_one_bucket_import_at_a_time_per_racer(settings, alice, alice_client, bob) -> None:
    """While Alice has a bucket read under way (its slot, in Redis, taken), her next one is
    refused before it reaches any server; Bob's is not; once hers ends, she may again."""
    from django.test import Client

    from tests.training.storage.hostile_bucket import hostile_server
    from training.services import bucket_imports

    settings.RACECRAFT_OUTBOUND_ALLOW = ["127.0.0.1"]
    bob_client = Client()
    bob_client.force_login(bob)
    with hostile_server() as server:
        server.mode = "html"
        with bucket_imports.bucket_read_slot(alice):
            busy = alice_client.post("/models/import/bucket/", _bucket_form(server.endpoint))
            assert busy.status_code == 400
            assert "An import from a bucket is already running for you" in busy.content.decode()
            assert server.counts.requests == 0
            other = bob_client.post("/models/import/bucket/", _bucket_form(server.endpoint))
            assert "annot reach an S3 server" in other.content.decode()
            assert server.counts.requests == 1
        again = alice_client.post("/models/import/bucket/", _bucket_form(server.endpoint))
        assert "annot reach an S3 server" in again.content.decode()
        assert server.counts.requests == 2
        # A failed read gave its slot back too.
        with bucket_imports.bucket_read_slot(alice):
            pass
