"""Importing a model through the services (issue 22, item 7): a bomb is refused in words that
keep the file's name as it is, nothing is saved, and the worker's memory does not grow."""

from __future__ import annotations

import gc

import psutil
import pytest

from tests.support import tar_gz
from tests.training.interchange.bomb_support import car_archive_files, fill, with_nodes
from training import services
from training.models import RacingModel
from training.services import ServiceError, background
from training.store import get_store

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
MB = 1024 * 1024


@pytest.fixture(scope="module")
def car_files() -> dict[str, bytes]:
    return car_archive_files()


def rss() -> int:
    gc.collect()
    return psutil.Process().memory_info().rss


def test_a_bomb_is_refused_naming_its_file_as_it_is(alice, car_files) -> None:
    bomb = with_nodes(car_files, *(fill(f"x{i}", [50_000_000]) for i in range(3)))
    before = rss()
    with pytest.raises(ServiceError) as refused:
        services.model_import(owner=alice, name="bomb", upload=bomb)
    assert refused.value.field == "archive"
    assert refused.value.sentence.startswith(
        "agent/model.pb: the constant 'x0' declares 50,000,000 values; a DeepRacer model has "
        "at most 40,000,000 in one tensor"
    )
    assert rss() - before < 40 * MB
    assert not RacingModel.objects.filter(name="bomb").exists()


def test_deep_json_on_the_worker_gives_its_reason_not_a_failed_task(alice, car_files) -> None:
    upload = tar_gz({**car_files, "model_metadata.json": b"[" * 200_000})
    background.model_import_start(owner=alice, name="deep", description="", data=upload)
    (key,) = get_store().list(background.UPLOADS)
    answer = background.model_import_run(
        owner_id=alice.pk, name="deep", description="", upload_key=key
    )
    assert answer == {
        "ok": False,
        "field": "archive",
        "error": "model_metadata.json: nested too deeply to read",
    }
    assert not RacingModel.objects.filter(name="deep").exists()
    assert get_store().list(background.UPLOADS) == []


def test_a_sentence_about_the_archive_is_still_capitalised(alice) -> None:
    with pytest.raises(ServiceError) as refused:
        services.model_import(owner=alice, name="junk", upload=b"junk")
    assert refused.value.sentence == "The upload is not a .tar.gz, .tar or .zip file"
