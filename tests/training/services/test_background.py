"""Model imports and car exports run on a worker, never in a web request (issue 10): the
upload is stored first, the page polls the task, and moves on to the model or offers the
download; per-user limits hold; only the owner reads a task. (Ida imports; Charlie must
never see her tasks.)"""

from __future__ import annotations

import io
import tarfile
import time

import pytest
from django.conf import settings
from django.contrib.auth import get_user_model
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from tests.conftest import _delete_prefixed
from tests.support import celery_worker_process
from training.models import RacingModel
from training.services import ServiceError, background
from training.services.downloads import virtual_model_archive
from training.store import get_store

REWARD = "def reward_function(params):\n    return 1.0\n"
POLL_TIMEOUT_S = 300.0
"""How long a task on the test's worker may take (a loaded machine is slow)."""


@pytest.fixture(autouse=True)
def _no_stale_tasks() -> None:
    """Tasks left queued by other tests (no worker there) would only slow this module's
    worker down (per-user counts are reset by tests/conftest.py)."""
    _delete_prefixed(settings.REDIS_URL, f"{settings.REDIS_PREFIX}interactive")


@pytest.fixture
def trained(ida_model) -> RacingModel:
    return ida_model()


@pytest.fixture
def ida(trained) -> Client:
    client = Client()
    client.force_login(trained.owner)
    return client


def wait_done(client: Client, poll: str) -> dict:
    deadline = time.monotonic() + POLL_TIMEOUT_S
    while True:
        body = client.get(poll).json()
        if body["status"] == "done":
            return body
        assert time.monotonic() < deadline, f"the task did not finish: {body}"
        time.sleep(0.3)


def poll_of(page: str) -> str:
    start = page.index('data-background-poll="') + len('data-background-poll="')
    return page[start : page.index('"', start)]


def uploads() -> list[str]:
    return get_store().list(background.UPLOADS)


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_import_and_car_export_run_on_a_worker(trained, ida, child_env, tmp_path) -> None:
    archive = SimpleUploadedFile("m.tar.gz", virtual_model_archive(trained), "application/gzip")
    response = ida.post("/models/import/", {"name": "again", "archive": archive})
    assert response.status_code == 302, response.content.decode()[-3000:]
    assert "?task=" in response["Location"]
    poll = poll_of(ida.get(response["Location"]).content.decode())
    # Nothing is imported in the request: the upload waits in the store for a worker.
    assert ida.get(poll).json() == {"status": "queued", "kind": "import"}
    assert len(uploads()) == 1 and not RacingModel.objects.filter(name="again").exists()
    charlie = Client()
    charlie.force_login(get_user_model().objects.create_user("charlie", password="x-pass-9"))
    assert charlie.get(poll).status_code == 404

    export = ida.get(f"/models/{trained.pk}/download/car/")
    assert export.status_code == 202  # the page with the progress, not the file
    export_poll = poll_of(export.content.decode())
    assert charlie.get(export_poll).status_code == 404
    # A second click follows the same export.
    assert poll_of(ida.get(f"/models/{trained.pk}/download/car/").content.decode()) == export_poll

    with celery_worker_process(
        queues=["interactive"], env=child_env, log_path=tmp_path / "worker.log"
    ):
        imported = wait_done(ida, poll)
        built = wait_done(ida, export_poll)
    copy = RacingModel.objects.get(owner=trained.owner, name="again")
    assert imported["ok"] is True and imported["next"] == f"/models/{copy.pk}/"
    assert copy.imported and copy.has_checkpoint and uploads() == []
    page = ida.get(imported["next"]).content.decode()
    assert "Model again imported." in page  # the status call left the message for this page

    assert built["ok"] is True and built["download"] == f"/models/{trained.pk}/download/car/"
    download = ida.get(built["download"])
    assert download.status_code == 200 and download["Content-Type"] == "application/gzip"
    with tarfile.open(fileobj=io.BytesIO(download.content)) as tar:
        assert {"agent/model.pb", "model_metadata.json"} <= set(tar.getnames())


@pytest.mark.django_db
def test_a_bad_upload_fails_on_the_worker_with_a_clear_message(trained) -> None:
    """The worker's side, run here: a damaged archive is refused in words, the upload is
    removed, nothing is saved."""
    task_id = background.model_import_start(owner=trained.owner, name="junk", description="",
                                            data=b"not an archive at all")  # fmt: skip
    assert task_id and len(uploads()) == 1
    (key,) = uploads()
    answer = background.model_import_run(owner_id=trained.owner.pk, name="junk", description="",
                                         upload_key=key)  # fmt: skip
    assert answer == {"ok": False, "field": "archive",
                      "error": "The upload is not a .tar.gz, .tar or .zip file"}  # fmt: skip
    assert uploads() == [] and not RacingModel.objects.filter(name="junk").exists()


@pytest.mark.django_db
def test_uploads_whose_import_never_ran_are_removed_after_a_day(trained) -> None:
    background.model_import_start(owner=trained.owner, name="fresh", description="", data=b"x")
    get_store().put_bytes(f"{background.UPLOADS}1000-u1-lost/upload", b"old")
    assert background.uploads_prune() == 1
    (kept,) = uploads()
    assert "-lost/" not in kept  # today's upload waits for its worker
    assert background.uploads_prune(older_than_s=-1) == 1 and uploads() == []


@pytest.mark.django_db
def test_per_user_limits_and_cheap_checks_answer_at_once(trained, settings, ida) -> None:
    settings.RACECRAFT_BACKGROUND_TASKS_PER_USER = 1
    with pytest.raises(ServiceError, match="already have a model named 'oval'"):
        background.model_import_start(owner=trained.owner, name="oval", description="", data=b"x")
    assert uploads() == []
    background.model_import_start(owner=trained.owner, name="one", description="", data=b"x")
    with pytest.raises(ServiceError, match="1 imports or car exports under way"):
        background.model_import_start(owner=trained.owner, name="two", description="", data=b"x")
    assert len(uploads()) == 1  # the refused one stored nothing
    # The page says so on the form, and a car export is refused the same way.
    upload = SimpleUploadedFile("m.tar.gz", b"x", "application/gzip")
    page = ida.post("/models/import/", {"name": "three", "archive": upload})
    assert page.status_code == 400 and "under way" in page.content.decode()
    refused = ida.get(f"/models/{trained.pk}/download/car/", follow=True)
    assert "under way" in refused.content.decode()
