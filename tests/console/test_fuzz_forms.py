"""Property-based fuzzing (Hypothesis) of every form and JSON endpoint, and of model and track
uploads: whatever arrives, the answer is never a 500 - a page with the form's errors, a clear
4xx, or a redirect after success - and nothing is left half-written (every model row has its
files; no stray track files)."""

from __future__ import annotations

import io
import json
import tarfile

import numpy as np
import pytest
from django.contrib.auth import get_user_model
from django.core.files.uploadedfile import SimpleUploadedFile
from django.core.management import CommandError, call_command
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from training.models import EvaluationJob, JobStatus, RacingModel, TrainingJob
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db, pytest.mark.slow]
SLOW_OK = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large]
FUZZ = settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=SLOW_OK)
REWARD = "def reward_function(params):\n    return 1.0\n"
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]

# Values a form field may receive: plausible ones, edge numbers, hostile text.
NASTY = st.one_of(
    st.text(max_size=80),
    st.text(alphabet=st.characters(codec="utf-8"), max_size=300),
    st.sampled_from(["", " ", "0", "-1", "1e309", "nan", "inf", "-inf", "99999999999999999999",
                     "racecraft_oval", "racecraft_summit", "native", "ccw", "cw", "discrete",
                     "continuous", "clipped_ppo", "sac", "RACECRAFT_LEAN_CNN", "huber",
                     "FRONT_FACING_CAMERA", "3", "5", "10", "0.5", "\x00", "../../etc/passwd",
                     "<script>alert(1)</script>", "' OR 1=1 --", "[]", "{}", "null", REWARD,
                     json.dumps(ACTIONS), "a" * 10_000]),
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)  # fmt: skip


def form_data(fields: list[str]) -> st.SearchStrategy[dict[str, str]]:
    return st.dictionaries(st.sampled_from([*fields, "generate", "extra", "csrfmiddlewaretoken"]),
                           NASTY, max_size=len(fields) + 2)  # fmt: skip


@pytest.fixture(autouse=True)
def store_dir(tmp_path, settings):
    from tests.conftest import clear_cache

    settings.STORE_DIR = tmp_path / "store"
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    # The sign-up and log-in throttles count in the cache: fuzzing must not exhaust them for
    # the tests that run after it.
    settings.RACECRAFT_SIGNUP_RATE = "100000/m"
    yield
    clear_cache()


@pytest.fixture
def alice_client(client):
    alice = get_user_model().objects.create_user("alice", password="pw-alice-123")
    client.force_login(alice)
    client.user = alice
    return client


def _trained_model(owner) -> RacingModel:
    model = RacingModel.objects.create(
        owner=owner, name="trained", track_id="racecraft_oval",
        neural_network="RACECRAFT_LEAN_CNN", action_space_type="discrete", action_space=ACTIONS,
        algorithm="clipped_ppo", reward_function=REWARD, has_checkpoint=True,
    )  # fmt: skip
    return model


def _nothing_half_made() -> None:
    store = get_store()
    for model in RacingModel.objects.all():
        assert store.exists(keys_for(model.pk).metadata) or model.name == "trained", model
    for job_model in (TrainingJob, EvaluationJob):
        for job in job_model.objects.filter(status=JobStatus.QUEUED):
            assert job.model.is_busy, job


def _check(response) -> None:
    assert response.status_code < 500, (response.status_code, response.content[:500])


MODEL_FIELDS = ["name", "description", "track_id", "direction", "race_type", "sensor",
                "action_space_type", "action_space", "gen_max_steering", "gen_steering_levels",
                "gen_max_speed", "gen_speed_levels", "steering_low", "steering_high",
                "speed_low", "speed_high", "algorithm", "neural_network", "batch_size",
                "num_epochs", "lr", "beta_entropy", "sac_alpha", "discount_factor", "loss_type",
                "num_episodes_between_training", "reward_function", "max_minutes"]  # fmt: skip


@FUZZ
@given(data=form_data(MODEL_FIELDS))
def test_fuzz_model_create_form(alice_client, data):
    _check(alice_client.post("/models/new/", data))
    _nothing_half_made()


@FUZZ
@given(data=form_data(["name", "description", "track_id", "direction", "reward_function",
                       "max_minutes"]))  # fmt: skip
def test_fuzz_clone_form(alice_client, data):
    model = RacingModel.objects.filter(name="trained").first() or _trained_model(alice_client.user)
    _check(alice_client.post(f"/models/{model.pk}/clone/", data))
    _nothing_half_made()


@FUZZ
@given(
    data=form_data(["track_id", "direction", "laps", "off_track_penalty_s", "crash_penalty_s"]),
    path=st.sampled_from(["evaluate", "train"]),
)
def test_fuzz_job_forms(alice_client, data, path, monkeypatch):
    monkeypatch.setattr("training.dispatch.send", lambda *a, **k: "fuzz-task")
    model = RacingModel.objects.filter(name="trained").first() or _trained_model(alice_client.user)
    _check(alice_client.post(f"/models/{model.pk}/{path}/", data))
    for job in TrainingJob.objects.filter(status=JobStatus.QUEUED):
        _check(alice_client.post(f"/jobs/training/{job.pk}/stop/", data))
    _nothing_half_made()


def _archive(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        for name, body in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(body)
            tar.addfile(info, io.BytesIO(body))
    return buffer.getvalue()


ARCHIVES = st.one_of(
    st.binary(max_size=2000),
    st.dictionaries(
        st.sampled_from(["model_metadata.json", "hyperparameters.json", "reward_function.py",
                         "model/best.zip", "model.pb", "../escape", "/abs", "a/../../b"]),
        st.one_of(st.binary(max_size=300), NASTY.map(str.encode),
                  st.just(json.dumps({"action_space": ACTIONS}).encode())),
        max_size=5,
    ).map(_archive),
)  # fmt: skip


@FUZZ
@given(name=NASTY, archive=ARCHIVES)
def test_fuzz_model_import_upload(alice_client, name, archive):
    upload = SimpleUploadedFile("upload.tar.gz", archive, content_type="application/gzip")
    _check(alice_client.post("/models/import/", {"name": name, "archive": upload}))
    assert not RacingModel.objects.filter(imported=True).exists()  # nothing valid was sent
    _nothing_half_made()


@FUZZ
@given(data=form_data(["username", "password1", "password2"]))
def test_fuzz_signup_form(client, data):
    _check(client.post("/accounts/signup/", data))


@FUZZ
@given(body=st.one_of(st.binary(max_size=500),
                      st.dictionaries(st.sampled_from(["source", "track", "direction", "x"]),
                                      st.one_of(NASTY, st.integers(), st.none(), st.lists(NASTY)),
                                      max_size=4).map(lambda d: json.dumps(d).encode())),
       as_json=st.booleans())  # fmt: skip
def test_fuzz_reward_validate_api(alice_client, body, as_json):
    kind = "application/json" if as_json else "application/x-www-form-urlencoded"
    response = alice_client.post("/api/reward/validate", body, content_type=kind)
    _check(response)
    assert response["Content-Type"].startswith("application/json")
    if response.status_code >= 400:
        assert response.json()["errors"][0]["message"]


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


TRACK_FILES = st.one_of(
    st.binary(max_size=3000),
    st.integers(min_value=0, max_value=60).flatmap(
        lambda n: st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32),
                           min_size=n * 6, max_size=n * 6)
        .map(lambda xs, n=n: _npy(np.array(xs, dtype=np.float64).reshape(n, 6)))),
)  # fmt: skip


@FUZZ
@given(data=TRACK_FILES, track_id=st.sampled_from(["fuzzed", "Bad Id!", "racecraft_oval", "x"]))
def test_fuzz_track_upload(tmp_path, settings, data, track_id):
    path = tmp_path / "upload.npy"
    path.write_bytes(data)
    tracks = settings.RACECRAFT_TRACKS_DIR
    try:
        call_command("import_track", str(path), "--id", track_id, "--overwrite",
                     stdout=io.StringIO())  # fmt: skip
    except CommandError as exc:
        assert str(exc)  # a clear message
        assert not (tracks / f"{track_id}.json").exists() or (tracks / f"{track_id}.npy").exists()
    else:
        assert (tracks / f"{track_id}.npy").exists() and (tracks / f"{track_id}.json").exists()
    for leftover in tracks.glob("*") if tracks.exists() else []:
        assert leftover.suffix in (".npy", ".json"), leftover
