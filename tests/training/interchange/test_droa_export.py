"""Downloads as DeepRacer-on-AWS (DRoA, aws-solutions/deepracer-on-aws) names and lays them
out: ``physicalmodel-<name>.tar.gz`` for the car (its content unchanged) and
``virtualmodel-<name>.tar.gz``, a model folder with every file DRoA's import reads, which
Racecraft imports back. (Ida downloads her own model.)"""

from __future__ import annotations

import io
import json
import tarfile

import pytest
from django.test import Client

from training import services
from training.interchange.export import build_virtual_model_archive, checkpoint_bytes
from training.models import RacingModel
from training.services.downloads import car_archive_build
from training.store import get_store, keys_for

REWARD = "def reward_function(params):\n    return 1.0\n"

DROA_IMPORT_READS = (
    "model_metadata.json",  # ImportHelper.parseModelMetadata
    "reward_function.py",  # ImportHelper.parseRewardFunction
    "training_params.yaml",  # ImportHelper.parseTrainingParams
    "ip/hyperparameters.json",  # ImportHelper.parseHyperparameters
)
"""The paths DRoA's import reads, relative to the uploaded folder: from
source/libs/lambda/src/import-workflow/utils/ImportHelper.ts (``parseImportedFiles``); the
browser uploads a folder's files under their path without the folder's own name
(source/apps/website/src/services/deepRacer/uploadUtils.ts, ``webkitRelativePath``)."""

DROA_FOLDER_CHECK = (
    "model_metadata.json",
    "reward_function.py",
    "training_params.yaml",
    "hyperparameters.json",
)
"""The file names DRoA's import page wants somewhere in the folder before it uploads
(source/apps/website/src/pages/ImportModel/constants.ts, ``REQUIRED_FILES_FOR_IMPORT``)."""


def names(archive: bytes) -> list[str]:
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        return [m.name for m in tar.getmembers() if m.isfile()]


def member(archive: bytes, name: str) -> bytes:
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        return tar.extractfile(name).read()


def assert_droa_imports(archive: bytes) -> None:
    """``archive`` holds everything DRoA's import reads, where it reads it."""
    found = names(archive)
    assert all(not n.startswith("/") and ".." not in n.split("/") for n in found)
    # DRoA's export has no top folder (assetpackaging.ts names members from the model's root).
    assert len({n.split("/", 1)[0] for n in found}) > 1
    assert set(DROA_IMPORT_READS) <= set(found), set(DROA_IMPORT_READS) - set(found)
    assert set(DROA_FOLDER_CHECK) <= {n.rsplit("/", 1)[-1] for n in found}


def test_the_virtual_model_has_what_droas_import_reads(ppo_discrete) -> None:
    params = b'WORLD_NAME: "racecraft_oval"\nRACE_TYPE: "TIME_TRIAL"\n'
    files = {
        "model/model_metadata.json": ppo_discrete.metadata.dumps(),
        "ip/hyperparameters.json": b'{"batch_size": 64}',
        "ip/training_params.yaml": params,
        "reward_function.py": REWARD.encode(),
        "model/best.zip": checkpoint_bytes(ppo_discrete.model),
    }
    archive = build_virtual_model_archive(files)
    assert_droa_imports(archive)
    # DeepRacer's network name for DeepRacer's tools (the SimApp refuses others), Racecraft's
    # kept aside, in both copies.
    top = json.loads(member(archive, "model_metadata.json"))
    assert member(archive, "model/model_metadata.json") == member(archive, "model_metadata.json")
    assert top["neural_network"] == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    assert top["racecraft_neural_network"] == "RACECRAFT_LEAN_CNN"
    assert top["action_space"] == json.loads(files["model/model_metadata.json"])["action_space"]
    assert member(archive, "training_params.yaml") == params
    del files["ip/training_params.yaml"]  # not ours to make up here: the download adds it
    assert "training_params.yaml" not in names(build_virtual_model_archive(files))


@pytest.fixture
def trained(ida_model) -> RacingModel:
    return ida_model(direction="cw")


@pytest.fixture
def ida(trained) -> Client:
    client = Client()
    client.force_login(trained.owner)
    return client


def test_downloads_are_named_as_droa_names_them(trained, ida) -> None:
    virtual = ida.get(f"/models/{trained.pk}/download/virtual/")
    assert virtual.status_code == 200
    assert virtual["Content-Disposition"] == 'attachment; filename="virtualmodel-oval.tar.gz"'
    assert_droa_imports(virtual.content)
    params = member(virtual.content, "training_params.yaml").decode()
    assert 'WORLD_NAME: "racecraft_oval"' in params and 'REVERSE_DIR: "true"' in params

    car = car_archive_build(trained)  # as the worker builds it; the download serves it
    physical = ida.get(f"/models/{trained.pk}/download/car/")
    assert physical.status_code == 200
    assert physical["Content-Disposition"] == 'attachment; filename="physicalmodel-oval.tar.gz"'
    assert physical.content == car  # only the name changed
    assert sorted(names(car)) == ["agent/model.pb", "model_metadata.json"]


def test_the_droa_laid_out_download_imports_back(trained, ida) -> None:
    archive = ida.get(f"/models/{trained.pk}/download/virtual/").content
    copy = services.model_import(owner=trained.owner, name="back", upload=archive)
    assert (copy.track_id, copy.direction, copy.seed) == ("racecraft_oval", "cw", 4242)
    assert copy.has_checkpoint and copy.import_note == ""


def test_a_model_stored_without_training_params_gets_them_in_its_download(trained) -> None:
    from training.services.downloads import virtual_model_archive
    from training.services.model_files import TRAINING_PARAMS

    store, prefix = get_store(), keys_for(trained.pk).prefix
    hyperparameters = store.get_bytes(f"{prefix}ip/hyperparameters.json")
    store.delete_prefix(f"{prefix}ip/")  # a folder at a time
    store.put_bytes(f"{prefix}ip/hyperparameters.json", hyperparameters)
    assert f"{prefix}{TRAINING_PARAMS}" not in store.list(prefix)
    archive = virtual_model_archive(trained)
    assert_droa_imports(archive)
    assert b'WORLD_NAME: "racecraft_oval"' in member(archive, "training_params.yaml")


def test_the_model_page_says_whether_droa_would_take_the_virtual_model(trained, ida) -> None:
    page = ida.get(f"/models/{trained.pk}/").content.decode()
    link = page[page.index('id="download-virtual"') :].split(">", 1)[0]
    assert "DeepRacer-on-AWS would refuse it" in link
    assert "DeepRacer 3-layer CNN, heads as in AWS" in link  # what to train with instead
