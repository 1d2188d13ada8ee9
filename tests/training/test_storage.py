"""The object store contract, run against a local folder and a real S3 server on loopback.

The S3 server is moto's ThreadedMotoServer on 127.0.0.1 (an ephemeral port; the
``s3_endpoint`` fixture of tests/support.py); the minio SDK talks plain HTTP to it, exactly as
it talks to MinIO in production.
"""

from __future__ import annotations

import os
import threading
import uuid
from datetime import UTC, datetime
from pathlib import Path

import pytest

from tests.support import S3_ACCESS_KEY, S3_SECRET_KEY
from training.interchange.layout import ModelKeys, evaluation_stamp, model_prefix
from training.storage import (
    LocalStore,
    MinioStore,
    ObjectNotFound,
    ObjectStore,
    StoreError,
    check_bucket_name,
    store_from_settings,
    validate_key,
)

ACCESS, SECRET = S3_ACCESS_KEY, S3_SECRET_KEY  # what the s3_endpoint fixture accepts


def minio_store(endpoint: str, bucket: str | None = None) -> MinioStore:
    bucket = bucket or f"deepracer-test-{uuid.uuid4().hex[:12]}"
    return MinioStore(endpoint, ACCESS, SECRET, secure=False, bucket=bucket, timeout=5)


@pytest.fixture(params=["local", "minio"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> ObjectStore:
    if request.param == "local":
        return LocalStore(tmp_path / "store")
    return minio_store(request.getfixturevalue("s3_endpoint"))


# --- the contract, for both backends ---------------------------------------------------------


def test_put_get_roundtrip(store: ObjectStore) -> None:
    store.put_bytes("7/model/model_metadata.json", b'{"a": 1}', content_type="application/json")
    assert store.get_bytes("7/model/model_metadata.json") == b'{"a": 1}'
    assert store.exists("7/model/model_metadata.json")


def test_overwrite_replaces(store: ObjectStore) -> None:
    store.put_bytes("k/a.bin", b"first")
    store.put_bytes("k/a.bin", b"second!")
    assert store.get_bytes("k/a.bin") == b"second!"
    assert store.list("k") == ["k/a.bin"]


def test_empty_and_binary_objects(store: ObjectStore) -> None:
    blob = bytes(range(256)) * 100
    store.put_bytes("b/empty", b"")
    store.put_bytes("b/blob", blob)
    assert store.get_bytes("b/empty") == b""
    assert store.get_bytes("b/blob") == blob


def test_missing_key(store: ObjectStore) -> None:
    assert not store.exists("nothing/here.txt")
    with pytest.raises(ObjectNotFound) as info:
        store.get_bytes("nothing/here.txt")
    assert info.value.key == "nothing/here.txt"
    assert isinstance(info.value, StoreError)


def test_ranged_reads(store: ObjectStore) -> None:
    data = bytes(range(256)) * 4
    store.put_bytes("m/videos/1.mp4", data, "video/mp4")
    assert store.stat_size("m/videos/1.mp4") == len(data)
    assert store.get_range("m/videos/1.mp4", 4, 8) == data[4:12]
    assert store.get_range("m/videos/1.mp4", 1020, 100) == data[1020:]  # fewer at the end
    assert store.get_range("m/videos/1.mp4", 0, 0) == b""
    with pytest.raises(ObjectNotFound):
        store.stat_size("m/videos/none.mp4")
    with pytest.raises(ObjectNotFound):
        store.get_range("m/videos/none.mp4", 0, 4)


def test_folder_is_not_an_object(store: ObjectStore) -> None:
    store.put_bytes("m/model/x.zip", b"x")
    assert not store.exists("m/model")
    with pytest.raises(ObjectNotFound):
        store.get_bytes("m/model")


def test_list_is_recursive_sorted_and_folder_scoped(store: ObjectStore) -> None:
    for key in ("1/b.txt", "1/a/z.txt", "1/a/y.txt", "10/c.txt", "2/d.txt"):
        store.put_bytes(key, key.encode())
    assert store.list("1") == ["1/a/y.txt", "1/a/z.txt", "1/b.txt"]
    assert store.list("1/") == store.list("1")
    assert store.list("1/a") == ["1/a/y.txt", "1/a/z.txt"]
    assert store.list("nope") == []
    assert store.list() == ["1/a/y.txt", "1/a/z.txt", "1/b.txt", "10/c.txt", "2/d.txt"]


def test_delete_prefix_removes_only_that_model(store: ObjectStore) -> None:
    keys, other = ModelKeys(5), ModelKeys(55)
    for key in (keys.metadata, keys.best, keys.simtrace(0), keys.video("e1"), other.metadata):
        store.put_bytes(key, b"x")
    assert store.delete_prefix(model_prefix(5)) == 4
    assert store.list() == [other.metadata]
    assert store.delete_prefix("5") == 0


def test_delete_prefix_refuses_the_whole_store(store: ObjectStore) -> None:
    store.put_bytes("a/b", b"x")
    for prefix in ("", "/", "../", "a/../"):
        with pytest.raises(StoreError):
            store.delete_prefix(prefix)
    assert store.list() == ["a/b"]


BAD_KEYS = [
    "",
    "/etc/passwd",
    "../outside",
    "a/../../outside",
    "a/./b",
    "a//b",
    "a/b/",
    "a\\..\\b",
    "a/\x00b",
    ".racecraft-tmp/x",
    "x" * 1100,
]


@pytest.mark.parametrize("key", BAD_KEYS)
def test_bad_keys_refused(store: ObjectStore, key: str) -> None:
    with pytest.raises(StoreError):
        store.put_bytes(key, b"x")
    with pytest.raises(StoreError):
        store.get_bytes(key)
    with pytest.raises(StoreError):
        store.exists(key)


def test_dotfiles_are_valid_keys(store: ObjectStore) -> None:
    store.put_bytes("m/model/.coach_checkpoint", b"13_Step-25173.ckpt")
    assert store.list("m") == ["m/model/.coach_checkpoint"]


# --- LocalStore specifics -------------------------------------------------------------------


def test_local_traversal_never_touches_outside(tmp_path: Path) -> None:
    store = LocalStore(tmp_path / "store")
    (tmp_path / "secret.txt").write_text("secret")
    for key in ("../secret.txt", "a/../../secret.txt", "/" + str(tmp_path / "secret.txt")):
        with pytest.raises(StoreError):
            store.get_bytes(key)
        with pytest.raises(StoreError):
            store.put_bytes(key, b"overwritten")
    assert (tmp_path / "secret.txt").read_text() == "secret"


def test_local_symlink_out_of_store_refused(tmp_path: Path) -> None:
    store = LocalStore(tmp_path / "store")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "f").write_text("outside")
    (tmp_path / "store" / "link").symlink_to(outside)
    with pytest.raises(StoreError, match="outside the store"):
        store.get_bytes("link/f")
    with pytest.raises(StoreError, match="outside the store"):
        store.put_bytes("link/g", b"x")
    with pytest.raises(StoreError, match="outside the store"):
        store.list("link")
    with pytest.raises(StoreError, match="outside the store"):
        store.delete_prefix("link")
    assert sorted(os.listdir(outside)) == ["f"]


def test_local_write_is_atomic(tmp_path: Path) -> None:
    """A failing write leaves the old object intact and no temporary file behind, and a
    reader running during many rewrites only ever sees complete objects."""
    store = LocalStore(tmp_path / "store")
    old, new = b"A" * 1_000_000, b"B" * 1_000_000
    store.put_bytes("m/big", old)

    class Boom(bytes):
        def __bytes__(self) -> bytes:
            raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        store.put_bytes("m/big", Boom(b"x"))
    assert store.get_bytes("m/big") == old

    seen: set[bytes] = set()
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            data = store.get_bytes("m/big")
            seen.add(data[:1] + data[-1:] + str(len(data)).encode())

    thread = threading.Thread(target=reader)
    thread.start()
    for i in range(20):
        store.put_bytes("m/big", new if i % 2 else old)
    stop.set()
    thread.join()
    assert seen <= {b"AA1000000", b"BB1000000"}
    assert store.list() == ["m/big"]
    assert os.listdir(tmp_path / "store" / ".racecraft-tmp") == []


def test_local_delete_prefix_prunes_empty_folders(tmp_path: Path) -> None:
    store = LocalStore(tmp_path / "store")
    store.put_bytes("m/a/b/c.txt", b"x")
    store.delete_prefix("m/a")
    assert sorted(os.listdir(tmp_path / "store")) == [".racecraft-tmp"]


def test_local_store_unwritable_root(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(StoreError):
        LocalStore(tmp_path / "file" / "store")


# --- MinioStore specifics -------------------------------------------------------------------


def test_minio_creates_missing_bucket_once(s3_endpoint: str) -> None:
    bucket = f"deepracer-new-{uuid.uuid4().hex[:8]}"
    first = minio_store(s3_endpoint, bucket)
    first.put_bytes("a", b"1")
    second = minio_store(s3_endpoint, bucket)  # bucket exists: reused, not recreated
    assert second.get_bytes("a") == b"1"
    assert second.client.bucket_exists(bucket)


@pytest.mark.parametrize("bucket", ["deepracer-models", "deepracer", "deepracer.team-1"])
def test_bucket_names_deepracer_tools_read(bucket: str) -> None:
    assert check_bucket_name(bucket) == bucket


@pytest.mark.parametrize(
    ("bucket", "message"),
    [
        ("models", "must start with 'deepracer'"),
        ("racecraft", "must start with 'deepracer'"),
        ("my-deepracer", "must start with 'deepracer'"),
        ("DeepRacer-x", "must start with 'deepracer'"),
        ("deepracer_x", "not a valid bucket name"),
        ("deepracer_Models", "not a valid bucket name"),
        ("deepracer-", "not a valid bucket name"),
        ("deepracer..x", "not a valid bucket name"),
        ("deepracer" + "x" * 60, "not a valid bucket name"),
    ],
)
def test_minio_bucket_name_rule(bucket: str, message: str) -> None:
    with pytest.raises(StoreError, match=message):
        check_bucket_name(bucket)
    with pytest.raises(StoreError, match=message):
        MinioStore("127.0.0.1:9", ACCESS, SECRET, bucket=bucket)


def test_minio_unreachable_server_is_a_store_error() -> None:
    store = MinioStore("127.0.0.1:9", ACCESS, SECRET, bucket="deepracer-x", timeout=1, retries=0)
    with pytest.raises(StoreError, match="127.0.0.1:9"):
        store.get_bytes("a")


def test_minio_wrong_credentials_are_a_store_error(s3_endpoint: str) -> None:
    store = minio_store(s3_endpoint)
    store.put_bytes("a", b"1")
    other = MinioStore(s3_endpoint, ACCESS, SECRET, secure=True, bucket=store.bucket, retries=0)
    with pytest.raises(StoreError):  # TLS against a plain-HTTP server
        other.get_bytes("a")


def test_minio_endpoint_with_scheme(s3_endpoint: str) -> None:
    store = MinioStore(f"http://{s3_endpoint}", ACCESS, SECRET, bucket="deepracer-scheme")
    store.put_bytes("a", b"1")
    assert store.endpoint == s3_endpoint
    with pytest.raises(StoreError):
        MinioStore("http://host:9000/path", ACCESS, SECRET)


# --- settings and keys ----------------------------------------------------------------------


def test_store_from_settings(tmp_path: Path, s3_endpoint: str) -> None:
    local = store_from_settings({"MINIO_ENDPOINT": "", "STORE_DIR": str(tmp_path / "s")})
    assert isinstance(local, LocalStore) and local.root == (tmp_path / "s").resolve()
    remote = store_from_settings(
        {
            "MINIO_ENDPOINT": s3_endpoint,
            "MINIO_ACCESS_KEY": ACCESS,
            "MINIO_SECRET_KEY": SECRET,
            "MINIO_SECURE": "false",
            "MINIO_BUCKET": "deepracer-settings",
            "STORE_DIR": str(tmp_path / "unused"),
        }
    )
    assert isinstance(remote, MinioStore) and not remote.secure
    remote.put_bytes("x", b"y")
    assert remote.get_bytes("x") == b"y"
    with pytest.raises(StoreError, match="MINIO_ACCESS_KEY"):
        store_from_settings({"MINIO_ENDPOINT": s3_endpoint})
    with pytest.raises(StoreError, match="MINIO_SECURE"):
        store_from_settings(
            {
                "MINIO_ENDPOINT": "h:1",
                "MINIO_ACCESS_KEY": "a",
                "MINIO_SECRET_KEY": "b",
                "MINIO_SECURE": "maybe",
            }
        )
    with pytest.raises(StoreError, match="STORE_DIR"):
        store_from_settings({})


def test_model_keys_layout() -> None:
    keys = ModelKeys("abc-1")
    assert keys.prefix == "abc-1/"
    assert keys.metadata == "abc-1/model/model_metadata.json"
    assert keys.hyperparameters == "abc-1/ip/hyperparameters.json"
    assert keys.reward_function == "abc-1/reward_function.py"
    assert keys.checkpoint("12_Step-300") == "abc-1/model/12_Step-300.zip"
    assert keys.best == "abc-1/model/best.zip" and keys.last == "abc-1/model/last.zip"
    assert keys.checkpoints_index == "abc-1/model/deepracer_checkpoints.json"
    assert keys.simtrace(3) == "abc-1/training-simtrace/3-iteration.csv"
    assert keys.training_metrics == "abc-1/metrics/TrainingMetrics.json"
    stamp = evaluation_stamp(datetime(2022, 7, 9, 20, 5, 9, tzinfo=UTC))
    assert stamp == "20220709200509"
    assert keys.evaluation_metrics(stamp) == "abc-1/metrics/EvaluationMetrics-20220709200509.json"
    assert (
        keys.evaluation_simtrace(stamp)
        == "abc-1/evaluation-20220709200509/evaluation-simtrace/0-iteration.csv"
    )
    assert (
        keys.legacy_evaluation_simtrace(9)
        == "abc-1/evaluation/9/evaluation-simtrace/0-iteration.csv"
    )
    assert keys.video(9) == "abc-1/videos/9.mp4"
    assert keys.car_export == "abc-1/export/car.tar.gz"
    for key in (keys.metadata, keys.simtrace(0), keys.video("e"), keys.car_export):
        assert validate_key(key) == key


@pytest.mark.parametrize("bad", ["", "../x", "a/b", "a b", True, "x" * 97])
def test_model_folders_are_one_safe_segment(bad: object) -> None:
    with pytest.raises(StoreError):
        model_prefix(bad)  # type: ignore[arg-type]
    with pytest.raises(StoreError):
        ModelKeys(1).checkpoint(bad if bad != "x" * 97 else "x" * 65)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", ["", "2022070920050", "2022-07-09T20:05", 20220709200509])
def test_evaluation_stamps_are_14_digits(bad: object) -> None:
    with pytest.raises(StoreError):
        ModelKeys(1).evaluation_simtrace(bad)  # type: ignore[arg-type]


def test_bad_iterations() -> None:
    with pytest.raises(StoreError):
        ModelKeys(1).simtrace(-1)
    with pytest.raises(StoreError):
        ModelKeys(1).simtrace("1")  # type: ignore[arg-type]
