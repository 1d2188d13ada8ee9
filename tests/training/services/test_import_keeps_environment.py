"""A virtual model carries its training environment (track, direction, seed, stop condition)
in ``ip/training_params.yaml``; importing it keeps them, or says why it could not."""

from __future__ import annotations

import io
import tarfile

import pytest
from django.contrib.auth import get_user_model

from training import services
from training.interchange.export import checkpoint_bytes
from training.models import RacingModel
from training.services.downloads import virtual_model_archive
from training.store import get_store, keys_for

pytestmark = pytest.mark.django_db
REWARD = "def reward_function(params):\n    return 1.0\n"


@pytest.fixture
def trained(ppo_discrete, tmp_path, settings) -> RacingModel:
    settings.STORE_DIR = tmp_path / "store"
    owner = get_user_model().objects.create_user("ida", password="x-long-pass-1")
    model = services.model_create(
        owner=owner, name="oval-ccw", track_id="racecraft_oval", direction="ccw",
        action_space=ppo_discrete.metadata.actions.to_metadata(), reward_function=REWARD,
        seed=4242, max_minutes=7, stop_when_ready=3, validate_reward=False,
    )  # fmt: skip
    get_store().put_bytes(keys_for(model.pk).best, checkpoint_bytes(ppo_discrete.model))
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    model.refresh_from_db()
    return model


def test_an_exported_model_imports_on_its_track_with_its_seed(trained) -> None:
    archive = virtual_model_archive(trained)
    copy = services.model_import(owner=trained.owner, name="back-again", upload=archive)
    assert (copy.track_id, copy.direction, copy.seed, copy.max_minutes,
            copy.stop_when_ready) == ("racecraft_oval", "ccw", 4242, 7, 3)  # fmt: skip
    assert copy.import_note == ""


@pytest.mark.parametrize("value", ["21", "-1", "three", ""])
def test_a_stop_when_ready_out_of_range_imports_as_off(trained, value) -> None:
    archive = _with_params(
        virtual_model_archive(trained), f'RACECRAFT_STOP_WHEN_READY: "{value}"\n'
    )
    copy = services.model_import(owner=trained.owner, name=f"ready-{len(value)}", upload=archive)
    assert copy.stop_when_ready == 0


def _with_params(archive: bytes, text: str) -> bytes:
    out = io.BytesIO()
    with (
        tarfile.open(fileobj=io.BytesIO(archive)) as src,
        tarfile.open(fileobj=out, mode="w:gz") as dst,
    ):  # noqa: E501
        for member in src.getmembers():
            data = src.extractfile(member).read() if member.isfile() else b""
            if member.name.endswith("training_params.yaml"):
                data = text.encode()
                member.size = len(data)
            dst.addfile(member, io.BytesIO(data))
    return out.getvalue()


def test_an_unknown_track_falls_back_and_says_so(trained) -> None:
    # H_track: a DeepRacer world that is not among the built-in DeepRacer tracks
    archive = _with_params(virtual_model_archive(trained), 'WORLD_NAME: "H_track"\n')
    copy = services.model_import(owner=trained.owner, name="elsewhere", upload=archive)
    assert copy.track_id != "H_track"
    assert "H_track" in copy.import_note and "not installed" in copy.import_note
