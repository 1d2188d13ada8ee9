"""Imported tracks by content (issue 25): a track uploaded on the web is recorded in the
database, and a machine that shares no disk with the web (here: another tracks folder) gets it
from there before a job needs it, byte for byte, once per version; a job on a track no machine
can have is refused before it is queued."""

from __future__ import annotations

import hashlib
import importlib
import io
import json
from dataclasses import replace

import numpy as np
import pytest
from django.apps import apps

from racing.track import Track, TrackError
from racing.tracks import TrackCatalog
from tests.training.services.factory import create
from training import services
from training.errors import ServiceError
from training.models import TrackFile
from training.rollout.envs import EnvSpec
from training.services.trackfiles import trackfile_save
from training.worker import common

pytestmark = pytest.mark.django_db


def _npy(track_id: str = "racecraft_oval", scale: float = 1.0) -> bytes:
    array = TrackCatalog().load(track_id).to_array() * scale
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


@pytest.fixture
def web(tmp_path, settings):
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "web-tracks"
    return settings.RACECRAFT_TRACKS_DIR


def test_an_upload_is_recorded_and_another_machine_gets_it_by_content(alice, web, tmp_path,
                                                                      settings):  # fmt: skip
    info = services.track_import(user=alice, data=_npy(), track_id="my_oval", name="My oval")
    row = TrackFile.objects.get(track_id="my_oval")
    stored = (web / "my_oval.npy").read_bytes()
    assert bytes(row.data) == stored and row.sha256 == hashlib.sha256(stored).hexdigest()
    assert row.name == "My oval" and row.created_by == alice and info.name == "My oval"
    assert (web / "my_oval.sha256").read_text() == row.sha256

    worker = tmp_path / "worker-tracks"  # the worker host's own folder: empty
    settings.RACECRAFT_TRACKS_DIR = worker
    assert services.tracks_sync() == ["my_oval"]
    assert (worker / "my_oval.npy").read_bytes() == stored
    track = TrackCatalog([worker]).load("my_oval")
    assert isinstance(track, Track) and track.name == "My oval"
    assert services.tracks_sync() == []  # cached by content: nothing written twice
    assert not [p for p in worker.iterdir() if p.name.startswith(".sync-")]  # no leftovers


def test_a_track_imported_again_is_written_anew_everywhere(web, tmp_path, settings):
    services.track_add(data=_npy(), track_id="my_oval")
    worker = tmp_path / "worker-tracks"
    assert services.tracks_sync(worker) == ["my_oval"]
    before = (worker / "my_oval.npy").read_bytes()
    services.track_add(data=_npy(scale=1.1), track_id="my_oval", overwrite=True)
    assert services.tracks_sync(worker) == ["my_oval"]
    after = (worker / "my_oval.npy").read_bytes()
    assert after != before and after == (web / "my_oval.npy").read_bytes()
    with pytest.raises(ServiceError, match="exists already"):
        services.track_add(data=_npy(), track_id="my_oval")


def test_an_id_taken_on_another_machine_is_taken_here(alice, web, tmp_path, settings):
    services.track_import(user=alice, data=_npy(), track_id="my_oval")
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "second-web"
    with pytest.raises(ServiceError, match="exists already"):
        services.track_import(user=alice, data=_npy(), track_id="my_oval")


def test_a_damaged_record_is_never_written(web, tmp_path):
    TrackFile.objects.create(track_id="bad", name="bad", data=b"not this", sha256="0" * 64)
    TrackFile.objects.create(track_id="../escape", name="x", data=b"x",
                             sha256=hashlib.sha256(b"x").hexdigest())  # fmt: skip
    worker = tmp_path / "worker-tracks"
    assert services.tracks_sync(worker) == []
    assert not (worker / "bad.npy").exists() and not (tmp_path / "escape.npy").exists()


def test_a_job_sees_the_track_on_a_worker_that_shares_no_disk(alice, web, tmp_path, settings):
    services.track_import(user=alice, data=_npy(), track_id="my_oval")
    model = create(alice, track_id="my_oval")
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "worker-tracks"
    spec = common.env_spec(model)
    assert spec.track_dirs == (str(tmp_path / "worker-tracks"),)
    sha = TrackFile.objects.get(track_id="my_oval").sha256
    assert spec.track_hashes == (("my_oval", sha),)  # the content, named on every machine
    assert common.env_spec(create(alice, name="m2")).track_hashes == ()  # built in: no row
    env = EnvSpec.from_json(json.loads(json.dumps(spec.to_json()))).make(None)
    try:
        assert env.track.track_id == "my_oval"
    finally:
        env.close()


def test_an_env_is_not_built_on_another_version_of_its_track(alice, web, tmp_path, settings):
    services.track_import(user=alice, data=_npy(), track_id="my_oval")
    spec = common.env_spec(create(alice, track_id="my_oval"))
    stale = tmp_path / "stale-worker"  # a machine that kept an older copy
    stale.mkdir()
    (stale / "my_oval.npy").write_bytes(_npy(scale=1.1))
    with pytest.raises(TrackError, match="copy of the track 'my_oval' is not the one"):
        replace(spec, track_dirs=(str(stale),)).make(None)


def test_a_remote_simulation_worker_reads_its_own_folder(alice, web, tmp_path, settings,
                                                         monkeypatch):  # fmt: skip
    services.track_import(user=alice, data=_npy(), track_id="my_oval")
    seen = {}
    monkeypatch.setattr(common, "serve_simulation", lambda **kwargs: seen.update(kwargs) or "ok")
    worker = tmp_path / "worker-tracks"
    settings.RACECRAFT_TRACKS_DIR = worker
    trainer_spec = {"track": "my_oval", "track_dirs": ["/trainer/only/var/tracks"]}
    sent = {}
    monkeypatch.setattr(common.dispatch, "send", lambda name, **kwargs: sent.update(kwargs) or "t")
    # What crosses the queue: the tracks by id and content, no folder, no Redis address.
    common.send_simulation(spec=trainer_spec, eval_spec=dict(trainer_spec), seed=1,
                           redis_url="redis://:pw@trainer-only:6379/0", prefix="p:")  # fmt: skip
    assert "track_dirs" not in sent["spec"] and "track_dirs" not in sent["eval_spec"]
    assert "redis_url" not in sent and "prefix" not in sent
    assert common.simulate_here(**json.loads(json.dumps(sent))) == "ok"
    assert seen["spec"]["track_dirs"] == seen["eval_spec"]["track_dirs"] == [str(worker)]
    assert seen["seed"] == 1 and (worker / "my_oval.npy").is_file()
    assert seen["redis_url"] == settings.REDIS_URL and seen["prefix"] == (
        settings.REDIS_PREFIX or ""
    )


def test_training_on_a_track_no_machine_has_is_refused_before_it_is_queued(alice, web):
    services.track_import(user=alice, data=_npy(), track_id="my_oval")
    model = create(alice, track_id="my_oval")
    TrackFile.objects.filter(track_id="my_oval").delete()
    for suffix in (".npy", ".json", ".sha256"):
        (web / f"my_oval{suffix}").unlink()
    with pytest.raises(ServiceError, match="'my_oval' is no longer in the catalogue"):
        services.training_start(model=model, user=alice)
    assert not model.training_jobs.exists()


def test_tracks_imported_before_the_database_held_them_are_adopted(web):
    web.mkdir(parents=True)
    (web / "old_oval.npy").write_bytes(_npy())
    (web / "old_oval.json").write_text(json.dumps({"name": "Old oval"}))
    migration = importlib.import_module("training.migrations.0007_track_files")
    migration.adopt_local_tracks(apps, None)
    row = TrackFile.objects.get(track_id="old_oval")
    assert row.name == "Old oval" and bytes(row.data) == (web / "old_oval.npy").read_bytes()
    migration.adopt_local_tracks(apps, None)  # again: nothing twice
    assert TrackFile.objects.filter(track_id="old_oval").count() == 1


def test_a_track_put_into_the_folder_by_hand_is_recorded_when_a_job_needs_it(alice, web):
    web.mkdir(parents=True)
    (web / "hand_oval.npy").write_bytes(_npy())
    model = create(alice, track_id="hand_oval")
    services.training_start(model=model, user=alice)
    row = TrackFile.objects.get(track_id="hand_oval")
    assert bytes(row.data) == (web / "hand_oval.npy").read_bytes()
    assert (web / "hand_oval.sha256").read_text() == row.sha256  # this copy is that content


def test_an_evaluation_on_a_track_put_there_by_hand_records_it_for_its_worker(alice, web):
    web.mkdir(parents=True)
    (web / "hand_oval.npy").write_bytes(_npy())
    model = create(alice)
    services.model_mark_checkpoint(model=model)
    job = services.evaluation_start(model=model, user=alice, track_id="hand_oval", enqueue=False)
    assert job.track_id == "hand_oval" and TrackFile.objects.filter(track_id="hand_oval").exists()


def test_the_web_lists_a_track_another_machine_imported(alice, web, client, settings):
    # Imported elsewhere (another web host, import_track on a worker): only the row is here.
    trackfile_save(track_id="far_oval", name="Far oval", data=_npy())
    settings.RACECRAFT_TRACKS_SYNC_S = 30
    client.force_login(alice)
    assert "Far oval" in client.get("/tracks/").content.decode()
    assert (web / "far_oval.npy").is_file()


def test_the_analysis_draws_a_track_imported_again_anew(alice, web):
    from training.services import analysis

    services.track_add(data=_npy(), track_id="my_oval")
    model = create(alice, track_id="my_oval")
    before = analysis._track(model).length
    services.track_add(data=_npy(scale=1.1), track_id="my_oval", overwrite=True)
    assert analysis._track(model).length == pytest.approx(before * 1.1, rel=1e-3)
