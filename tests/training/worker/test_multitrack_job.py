"""Multi-track training end to end: a model created on the command line to train on two
tracks at once (the racing preset, the oval and the summit driven clockwise) trains through
the real job runner with sandboxed rollouts, and its logs and metrics show both tracks: the
episode rows, TrainingMetrics.json (training and evaluation entries), the sim-trace's track
lengths, training_params.yaml and the model page."""

from __future__ import annotations

import csv
import io
import json

import pytest
from django.contrib.auth import get_user_model
from django.core.management import call_command
from django.test import Client

from racing.tracks import TrackCatalog
from tests.support import train_in_thread
from training import services
from training.models import EpisodeMetric, RacingModel
from training.services.model_files import TRAINING_PARAMS
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]
TRACKS = {"racecraft_oval", "racecraft_summit"}
SMALL = {"num_episodes_between_training": 8, "num_epochs": 3, "batch_size": 32,
         "discount_factor": 0.99}  # fmt: skip


def test_a_model_trains_on_two_tracks_and_its_logs_show_both(store_dir, tmp_path) -> None:
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    hyperparameters = tmp_path / "hyperparameters.json"
    hyperparameters.write_text(json.dumps(SMALL))
    out = io.StringIO()
    call_command(
        "racecraft_create_model", "--owner", "alice", "--name", "two-tracks",
        "--preset", "racing", "--hyperparameters", str(hyperparameters),
        "--track", "racecraft_oval", "--also-train-on", "racecraft_summit:cw",
        "--minutes", "30", "--seed", "4", stdout=out,
    )  # fmt: skip
    model = RacingModel.objects.get(name="two-tracks")
    assert "on racecraft_oval (native) + racecraft_summit (cw)" in out.getvalue()
    assert model.extra_tracks == [["racecraft_summit", "cw"]]

    job = services.training_start(model=model, user=alice, enqueue=False)
    job = train_in_thread(job, alice, iterations=2, within_s=600)
    assert job.status == "COMPLETED", job.error

    rows = EpisodeMetric.objects.filter(job=job)
    assert {r.track for r in rows.filter(phase="training")} == TRACKS
    assert {r.track for r in rows.filter(phase="evaluation")} == TRACKS

    store, keys = get_store(), keys_for(model.pk)
    metrics = json.loads(store.get_bytes(keys.training_metrics))["metrics"]
    for phase in ("training", "evaluation"):
        assert {m["track"] for m in metrics if m["phase"] == phase} == TRACKS, phase

    # The sim-trace: every episode of the metrics is in it, driven on its track's length.
    lengths = {t: round(TrackCatalog().load(t).length, 2) for t in TRACKS}
    trace = list(csv.DictReader(io.StringIO(store.get_bytes(keys.simtrace(0)).decode())))
    length_of = {int(r["episode"]): round(float(r["track_len"]), 2) for r in trace}
    first = [m for m in metrics if m["phase"] == "training"][
        : SMALL["num_episodes_between_training"]
    ]
    assert {m["episode"] - 1 for m in first} == set(length_of)
    for m in first:
        assert length_of[m["episode"] - 1] == lengths[m["track"]], m

    params = store.get_bytes(keys.prefix + TRAINING_PARAMS).decode()
    assert 'WORLD_NAME: "racecraft_oval"' in params
    assert 'RACECRAFT_TRACKS: "racecraft_oval:native,racecraft_summit:cw"' in params

    client = Client()
    client.force_login(alice)
    page = client.get(f"/models/{model.pk}/").content.decode()
    assert "Also trains on" in page and "racecraft_summit (cw)" in page

    # The community's reader takes the file as it is (the extra key is ignored).
    reader = pytest.importorskip("deepracer.logs")
    local = tmp_path / "TrainingMetrics.json"
    local.write_bytes(store.get_bytes(keys.training_metrics))
    read = reader.TrainingMetrics(None, fname=str(local)).metrics
    assert len(read[read["phase"] == "training"]) == len(rows.filter(phase="training"))
