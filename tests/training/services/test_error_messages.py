"""What a user reads when the store, an import or the task queue fails says what failed and
what to do, never an object key, the store's folder or endpoint, a broker address or a
secret (issue 10). Each failure is provoked with a store whose errors carry all of those, as
MinIO's and the local folder's do; the log keeps them for the administrator."""

from __future__ import annotations

import pytest

from tests.training.services.factory import ACTIONS, REWARD
from training import services
from training.models import RacingModel
from training.services import ServiceError, background, downloads, rewards
from training.storage import LocalStore, StoreError, StoreUnavailable
from training.store import get_store, keys_for

SECRETS = ("minio.internal", "9000", "s3cr3t-key", "/srv/racecraft", "u1-", "model/", "best.zip",
           "redis", "sock", "racecraft-uploads")  # fmt: skip
"""Words of the store's and broker's own messages that a user must never read."""
LEAKY = "cannot write 'u1-m1/model/best.zip' at MinioStore(http://minio.internal:9000/s3cr3t-key) /srv/racecraft"  # noqa: E501

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


class RefusingStore(LocalStore):
    """Reads and writes fail with the kind of words a real store uses."""

    def __init__(self, root, kind: type[StoreError] = StoreError) -> None:
        super().__init__(root)
        self.kind = kind

    def put_bytes(self, key, data, content_type="application/octet-stream") -> None:
        raise self.kind(LEAKY)

    def get_bytes(self, key) -> bytes:
        raise self.kind(LEAKY)

    def list(self, prefix: str = "") -> list[str]:
        raise self.kind(LEAKY)

    def delete_prefix(self, prefix: str) -> int:
        raise self.kind(LEAKY)


@pytest.fixture
def model(alice) -> RacingModel:
    created = services.model_create(owner=alice, name="m1", track_id="racecraft_oval",
                                    action_space=ACTIONS, reward_function=REWARD,
                                    validate_reward=False)  # fmt: skip
    get_store().put_bytes(keys_for(created.pk).best, b"weights")
    RacingModel.objects.filter(pk=created.pk).update(has_checkpoint=True)
    created.refresh_from_db()
    return created


@pytest.fixture(params=[StoreError, StoreUnavailable])
def refusing(request, monkeypatch, store_dir) -> RefusingStore:
    store = RefusingStore(store_dir, request.param)
    for module in ("models", "downloads", "background"):
        monkeypatch.setattr(f"training.services.{module}.get_store", lambda: store)
    return store


def assert_clean(message: str) -> None:
    assert message
    for word in SECRETS:
        assert word not in message, (word, message)


def refusal(call) -> str:
    with pytest.raises(ServiceError) as info:
        call()
    assert_clean(info.value.message)
    return info.value.message


def test_store_failures_say_what_failed_in_plain_words(alice, model, refusing) -> None:
    messages = [
        refusal(lambda: services.model_create(owner=alice, name="m2", track_id="racecraft_oval",
                                              action_space=ACTIONS, reward_function=REWARD,
                                              validate_reward=False)),
        refusal(lambda: services.model_clone(model=model, owner=alice, name="m3",
                                             reward_check="none")),
        refusal(lambda: downloads.virtual_model_archive(model)),
        refusal(lambda: downloads.logs_archive(model)),
        refusal(lambda: downloads.onnx_policy(model)),
        refusal(lambda: background.model_import_start(owner=alice, name="m4", description="",
                                                      data=b"archive")),
        refusal(lambda: services.model_delete(model=model, user=alice)),
    ]  # fmt: skip
    assert "files could not be written" in messages[0] or "unavailable" in messages[0]
    assert any("try again" in m for m in messages)
    model.refresh_from_db()
    assert_clean(model.error)  # what the page shows after the failed delete


def test_a_car_export_whose_store_refuses_says_so(model, monkeypatch, store_dir) -> None:
    """In the worker: the answer the page shows."""
    store = RefusingStore(store_dir, StoreError)
    for module in ("downloads", "background"):
        monkeypatch.setattr(f"training.services.{module}.get_store", lambda: store)
    answer = background.car_export_run(model_id=model.pk)
    assert answer["ok"] is False
    assert_clean(answer["error"])


def test_an_import_whose_upload_vanished_says_so(alice, store_dir) -> None:
    answer = background.model_import_run(owner_id=alice.pk, name="gone", description="",
                                         upload_key="racecraft-uploads/u1-x/upload")  # fmt: skip
    assert answer == {"ok": False, "field": None,
                      "error": "The upload is gone from the store; upload it again"}  # fmt: skip
    assert_clean(answer["error"])


def test_imports_name_what_is_wrong_in_the_archive_only(alice) -> None:
    for data in (b"", b"junk", b"\x1f\x8b\x08\x00garbage"):
        message = refusal(lambda d=data: services.model_import(owner=alice, name="x", upload=d))
        assert "upload" in message or "archive" in message


def test_a_queue_that_cannot_be_reached_is_said_without_its_address(alice, monkeypatch):
    from celery import current_app

    def down(*args, **kwargs):
        raise ConnectionError("Error 2 connecting to unix socket: /srv/racecraft/redis.sock")

    monkeypatch.setattr(current_app, "send_task", down)
    message = refusal(lambda: rewards.reward_validation_start(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval",
        direction="native"))  # fmt: skip
    assert "try again in a minute" in message
    message = refusal(lambda: background.model_import_start(owner=alice, name="q",
                                                            description="", data=b"x"))  # fmt: skip
    assert "try again in a minute" in message


def test_redis_down_refuses_validations_and_imports_in_words(alice, settings, tmp_path):
    """Redis holds the per-user limits and the queue: when it cannot be reached the user is
    told to try again (no 500, no socket path)."""
    settings.REDIS_URL = f"unix://{tmp_path / 'nobody.sock'}?db=0"
    assert not rewards.reward_validation_passed(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval", direction="native"
    )
    message = refusal(lambda: rewards.reward_validation_start(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval",
        direction="native"))  # fmt: skip
    assert "try again in a minute" in message
    message = refusal(lambda: background.model_import_start(owner=alice, name="r",
                                                            description="", data=b"x"))  # fmt: skip
    assert "try again in a minute" in message
    assert get_store().list(background.UPLOADS) == []
