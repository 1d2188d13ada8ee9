"""One builder of the car archive in the services: the download, the background export and
the export after training all keep :func:`car_archive_build`'s bytes in the store, which are
the interchange builder's, byte for byte."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model

from training.interchange import carmodel
from training.models import RacingModel
from training.rl.checkpoints import checkpoint_bytes
from training.services import background, downloads, model_create
from training.services.model_files import model_metadata
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
REWARD = "def reward_function(params):\n    return 1.0\n"


@pytest.fixture
def trained(ppo_discrete) -> RacingModel:
    owner = get_user_model().objects.create_user("ida", password="x-long-pass-1")
    model = model_create(
        owner=owner, name="oval", track_id="racecraft_oval",
        action_space=ppo_discrete.metadata.actions.to_metadata(), reward_function=REWARD,
        validate_reward=False,
    )  # fmt: skip
    get_store().put_bytes(keys_for(model.pk).best, checkpoint_bytes(ppo_discrete.model))
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    model.refresh_from_db()
    return model


def test_the_download_builds_once_into_the_store_then_reads_it(trained, monkeypatch) -> None:
    assert background.car_export_ready(trained) is None
    expected = carmodel.build_car_archive(
        model_metadata(trained), get_store().get_bytes(keys_for(trained.pk).best)
    )
    assert downloads.car_model_archive(trained) == expected
    assert get_store().get_bytes(keys_for(trained.pk).car_export) == expected
    assert background.car_export_ready(trained) == expected

    def no_build(*args, **kwargs):
        raise AssertionError("built again")

    monkeypatch.setattr(downloads, "build_car_archive", no_build)
    assert downloads.car_model_archive(trained) == expected  # from the store


def test_building_again_replaces_the_stored_archive(trained) -> None:
    get_store().put_bytes(keys_for(trained.pk).car_export, b"stale")
    assert downloads.car_model_archive(trained) == b"stale"
    built = downloads.car_archive_build(trained)
    assert built != b"stale" and downloads.car_model_archive(trained) == built
