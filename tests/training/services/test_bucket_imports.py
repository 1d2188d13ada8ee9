"""Importing a model straight from a DeepRacer-for-Cloud bucket, through a real S3 server (moto
on loopback, signing checked): the service, the command line and the import page read only
the files an import needs, the model drives as the one it came from, every failure is one
clear sentence on the field to fix, and the keys are never kept: not in the database, the
store, Redis, a log line or a page. (Alice imports; the bucket is her DRfC install's.)"""

from __future__ import annotations

import io
import json
import logging
import tarfile
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import redis
from django.conf import settings
from django.core.management import call_command
from django.core.management.base import CommandError
from django.core.signals import got_request_exception
from django.db import connection
from django.test import Client

from tests.support import S3_ACCESS_KEY, S3_SECRET_KEY
from training import services
from training.interchange.export import build_car_archive
from training.models import RacingModel
from training.rl.checkpoints import load_checkpoint
from training.services import ServiceError, background, bucket_imports
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]

BUCKET, PREFIX = "bucket", "rl-deepracer-sagemaker"
REWARD = b"def reward_function(params):\n    return float(params['speed'])\n"
HYPERPARAMETERS = json.dumps({"batch_size": 64, "lr": 0.0003, "num_epochs": 10}).encode()
LOGS = {
    "training-simtrace/0-iteration.csv": b"episode,steps\n",
    "metrics/TrainingMetrics.json": b'{"metrics": []}',
    "sagemaker-robomaker-artifacts/log.txt": b"log",
    "training_log.txt": b"a log at the prefix's top",
}
"""Files of a DRfC prefix that an import never reads."""
WANTED = {
    "model/model_metadata.json",
    "model/deepracer_checkpoints.json",
    "model/.coach_checkpoint",
    "model/model_3.pb",
    "ip/hyperparameters.json",
    "reward_function.py",
    "training_params.yaml",
}


@dataclass(frozen=True)
class Drfc:
    """The moto server, and the keys of its IAM user who may read the bucket."""

    endpoint: str
    access_key: str
    secret_key: str

    def kwargs(self, **overrides: object) -> dict:
        return {"endpoint": self.endpoint, "bucket": BUCKET, "prefix": PREFIX,
                "access_key": self.access_key, "secret_key": self.secret_key,
                "secure": False, **overrides}  # fmt: skip


def drfc_prefix(ppo_discrete) -> dict[str, bytes]:
    """A DRfC model prefix: Racecraft's car export of the tiny model as DeepRacer's frozen graph
    of iteration 3 (the best), a graph of iteration 1 that must not be read (not a graph at
    all), the second worker's training parameters, and logs."""
    car = build_car_archive(ppo_discrete.metadata, ppo_discrete.model)
    with tarfile.open(fileobj=io.BytesIO(car)) as tar:
        files = {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}
    checkpoints = {"best_checkpoint": {"name": "3_Step-300.ckpt"},
                   "last_checkpoint": {"name": "1_Step-100.ckpt"}}  # fmt: skip
    return {
        "model/model_metadata.json": files["model_metadata.json"],
        "model/model_3.pb": files["agent/model.pb"],
        "model/model_1.pb": b"not a graph: reading it would fail the import",
        "model/deepracer_checkpoints.json": json.dumps(checkpoints).encode(),
        "model/.coach_checkpoint": b"1_Step-100.ckpt\n",
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "training_params_2.yaml": b"WORLD_NAME: racecraft_oval\n",
        "training_params.yaml": b"WORLD_NAME: racecraft_summit\nRACECRAFT_SEED: '77'\n",
        **LOGS,
    }


@pytest.fixture(scope="module")
def drfc(s3_endpoint, ppo_discrete) -> Iterator[Drfc]:
    """The bucket holds the model at :data:`PREFIX`, only logs at ``logs-only/``; from then on
    the server checks every request's signature against its IAM user's keys."""
    import boto3
    from moto import settings as moto_settings
    from moto.core.authorization import ActionAuthenticatorMixin

    setup = {"endpoint_url": f"http://{s3_endpoint}", "region_name": "us-east-1",
             "aws_access_key_id": S3_ACCESS_KEY,
             "aws_secret_access_key": S3_SECRET_KEY}  # fmt: skip
    iam = boto3.client("iam", **setup)
    iam.create_user(UserName="drfc")
    policy = {"Version": "2012-10-17",
              "Statement": [{"Effect": "Allow", "Action": "s3:*", "Resource": "*"}]}  # fmt: skip
    arn = iam.create_policy(PolicyName="s3", PolicyDocument=json.dumps(policy))["Policy"]["Arn"]
    iam.attach_user_policy(UserName="drfc", PolicyArn=arn)
    key = iam.create_access_key(UserName="drfc")["AccessKey"]
    s3 = boto3.client("s3", **setup)
    s3.create_bucket(Bucket=BUCKET)
    for name, data in drfc_prefix(ppo_discrete).items():
        s3.put_object(Bucket=BUCKET, Key=f"{PREFIX}/{name}", Body=data)
    for name, data in LOGS.items():
        s3.put_object(Bucket=BUCKET, Key=f"logs-only/{name}", Body=data)
    saved = moto_settings.INITIAL_NO_AUTH_ACTION_COUNT
    moto_settings.INITIAL_NO_AUTH_ACTION_COUNT, ActionAuthenticatorMixin.request_count = 0, 0
    try:
        yield Drfc(s3_endpoint, key["AccessKeyId"], key["SecretAccessKey"])
    finally:
        moto_settings.INITIAL_NO_AUTH_ACTION_COUNT = saved


@pytest.fixture(autouse=True)
def outbound_allows_loopback(settings) -> None:
    """The moto server listens on loopback, which a user's address may reach only when the
    operator allows it, as for a DeepRacer-for-Cloud MinIO on the same machine."""
    settings.RACECRAFT_OUTBOUND_ALLOW = ["127.0.0.1"]


def closed_port() -> str:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return f"127.0.0.1:{probe.getsockname()[1]}"  # nothing listens once it is closed


def refusal(call) -> ServiceError:
    with pytest.raises(ServiceError) as refused:
        call()
    return refused.value


# ------------------------------------------------------------------------------ where keys go
def assert_keys_nowhere(drfc: Drfc, caplog: pytest.LogCaptureFixture, *pages: str) -> None:
    """Neither key in any row of any table, any object of the store, any value under the
    tests' Redis prefix (the task queue and its results), a log record or a page."""
    secrets = (drfc.secret_key, drfc.access_key)
    with connection.cursor() as cursor:
        for table in connection.introspection.table_names(cursor):
            # Every column as text, in SQL both PostgreSQL and SQLite (the README's default) read.
            cursor.execute(f'SELECT * FROM "{table}"')
            for values in cursor.fetchall():
                row = " ".join(
                    bytes(v).decode("latin-1") if isinstance(v, bytes | memoryview) else str(v)
                    for v in values
                )
                assert not any(s in row for s in secrets), f"a key in a row of {table}"
    store = get_store()
    for name in store.list(""):
        data = store.get_bytes(name)
        assert not any(s.encode() in data for s in secrets), f"a key in the store's {name}"
    for name, value in redis_values():
        assert not any(s.encode() in value for s in secrets), f"a key in Redis's {name}"
    for record in caplog.records:
        text = f"{record.getMessage()} {record.exc_text or ''}"
        # The S3 server (moto, in this process) logs the access key it was sent: it is the
        # other end, whose logs are the bucket owner's. No record, its own included, holds the
        # secret.
        server = record.name.startswith(("moto", "werkzeug"))
        for secret in secrets[:1] if server else secrets:
            assert secret not in text, f"a key in a log line of {record.name}: {text[:200]}"
    for page in pages:
        assert not any(s in page for s in secrets), "a key in a page"


def redis_values() -> list[tuple[bytes, bytes]]:
    """Every value under the tests' Redis prefix: the task queue, results, per-user counts."""
    client = redis.Redis.from_url(settings.REDIS_URL)
    readers = {
        "string": lambda n: [client.get(n)],
        "list": lambda n: client.lrange(n, 0, -1),
        "set": lambda n: list(client.smembers(n)),
        "hash": lambda n: [*client.hkeys(n), *client.hvals(n)],
        "zset": lambda n: client.zrange(n, 0, -1),
    }
    try:
        return [
            (name, value or b"")
            for name in client.scan_iter(match=f"{settings.REDIS_PREFIX}*", count=1000)
            for value in readers.get(client.type(name).decode(), lambda n: [])(name)
        ]
    finally:
        client.close()


def assert_drives_as(model: RacingModel, ppo_discrete) -> None:
    from racing.env import RacingEnv

    imported = load_checkpoint(get_store().get_bytes(keys_for(model.pk).best),
                               services.model_metadata(model))  # fmt: skip
    env = RacingEnv("racecraft_summit")
    obs, _ = env.reset(seed=4)
    for _ in range(10):
        ours, _ = imported.predict(obs, deterministic=True)
        theirs, _ = ppo_discrete.model.predict(obs, deterministic=True)
        assert int(ours) == int(theirs)
        obs, *_ = env.step(int(theirs))
    env.close()


# ------------------------------------------------------------------------------ the service
def test_only_the_files_an_import_needs_are_read(drfc) -> None:
    archive = bucket_imports.bucket_model_archive(**drfc.kwargs(prefix=f"/{PREFIX}/"))
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        files = {m.name: tar.extractfile(m).read() for m in tar.getmembers()}
    assert set(files) == WANTED  # not the other graph, the second worker's params, nor logs
    assert files["training_params.yaml"].startswith(b"WORLD_NAME: racecraft_summit")
    assert files["reward_function.py"] == REWARD


@pytest.mark.slow
def test_the_service_imports_a_drfc_model_that_drives_the_same(
    drfc, alice, ppo_discrete, caplog
) -> None:
    caplog.set_level(logging.DEBUG)
    model = services.model_import_from_bucket(owner=alice, name="from-drfc", **drfc.kwargs())
    assert model.imported and model.has_checkpoint
    assert "Imported from DeepRacer's model/model_3.pb" in model.description
    assert model.reward_function == REWARD.decode()
    assert (model.track_id, model.seed) == ("racecraft_summit", 77)
    assert model.hyperparameters["batch_size"] == 64
    assert_drives_as(model, ppo_discrete)
    assert_keys_nowhere(drfc, caplog)


@pytest.mark.parametrize(
    "change, field, words",
    [
        ({"secret_key": "not-the-secret"}, "secret_key",
         "access denied: the secret key does not match the access key"),
        ({"access_key": "AKIAUNKNOWNUNKNOWN00"}, "access_key",
         "access denied: the server does not know this access key"),
        ({"bucket": "no-such-bucket"}, "bucket",
         "there is no bucket 'no-such-bucket' at http://"),
        ({"prefix": "empty-prefix"}, "prefix",
         "no DeepRacer model at s3://bucket/empty-prefix: there is nothing there"),
        ({"prefix": "logs-only"}, "prefix",
         "no DeepRacer model at s3://bucket/logs-only: no model/model_metadata.json"),
        ({"prefix": "a/../b"}, "prefix", "'a/../b' is not a folder name"),
        ({"endpoint": "localhost:9000/path"}, "endpoint", "the endpoint must be host:port"),
    ],
)  # fmt: skip
def test_each_failure_is_one_sentence_on_its_field(drfc, alice, change, field, words) -> None:
    refused = refusal(
        lambda: services.model_import_from_bucket(owner=alice, name="x", **drfc.kwargs(**change))
    )
    assert (refused.field, refused.message[: len(words)]) == (field, words)
    assert drfc.secret_key not in refused.message and drfc.access_key not in refused.message
    assert not RacingModel.objects.filter(name="x").exists()


def test_a_host_the_operator_allows_by_name_is_looked_up_once(drfc, settings, monkeypatch):
    """A LAN MinIO named in RACECRAFT_OUTBOUND_ALLOW is read (here a made-up name for the moto
    server's loopback address), and its name is looked up once for the whole import: every
    connection goes to the address that was checked, none asks the resolver again."""
    import socket

    settings.RACECRAFT_OUTBOUND_ALLOW = ["drfc-minio"]
    real, lookups = socket.getaddrinfo, []

    def resolve(host, port, *args, **kwargs):
        if host == "drfc-minio":
            lookups.append(host)
            host = "127.0.0.1"
        return real(host, port, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", resolve)
    endpoint = f"drfc-minio:{drfc.endpoint.rpartition(':')[2]}"
    archive = bucket_imports.bucket_model_archive(**drfc.kwargs(endpoint=endpoint))
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        assert {m.name for m in tar.getmembers()} == WANTED
    assert lookups == ["drfc-minio"]
    settings.RACECRAFT_OUTBOUND_ALLOW = []  # not allowed: the same loopback is refused
    refused = refusal(lambda: bucket_imports.bucket_model_archive(**drfc.kwargs(endpoint=endpoint)))
    assert refused.message.startswith(f"cannot reach an S3 server at http://{endpoint}")


def test_an_unreachable_endpoint_is_refused_within_seconds(drfc, alice) -> None:
    for endpoint in (closed_port(), "no-such-host.invalid:9000"):
        started = time.monotonic()
        refused = refusal(lambda e=endpoint: services.model_import_from_bucket(
            owner=alice, name="x", **drfc.kwargs(endpoint=e)))  # fmt: skip
        assert time.monotonic() - started < 5
        assert refused.field == "endpoint"
        assert refused.message.startswith(f"cannot reach an S3 server at http://{endpoint}")


def test_a_model_over_the_import_limit_is_refused_before_it_is_read(
    drfc, alice, monkeypatch
) -> None:
    from training.interchange.archive import ImportLimits

    monkeypatch.setattr(bucket_imports, "ImportLimits", lambda: ImportLimits(max_upload_bytes=6000))
    refused = refusal(lambda: bucket_imports.bucket_model_archive(**drfc.kwargs()))
    assert refused.field == "prefix"
    assert "is larger than" in refused.message and "the most imported" in refused.message


# ------------------------------------------------------------------------------ command line
@pytest.mark.slow
def test_the_command_imports_from_a_bucket_with_keys_from_the_environment(
    drfc, alice, ppo_discrete, monkeypatch, caplog
) -> None:
    caplog.set_level(logging.DEBUG)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", drfc.access_key)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", drfc.secret_key)
    out, err = io.StringIO(), io.StringIO()
    call_command("racecraft_import", "--from-bucket", drfc.endpoint, BUCKET, PREFIX,
                 "--owner", "alice", "--name", "cli-drfc", stdout=out, stderr=err)  # fmt: skip
    model = RacingModel.objects.get(owner=alice, name="cli-drfc")
    assert f"Imported model {model.pk}: cli-drfc" in out.getvalue()
    assert_drives_as(model, ppo_discrete)
    assert_keys_nowhere(drfc, caplog, out.getvalue(), err.getvalue())


def test_the_command_takes_keys_only_from_the_environment_or_a_prompt(
    drfc, alice, monkeypatch
) -> None:
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", drfc.access_key)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "not-the-secret")
    with pytest.raises(CommandError, match="access denied: the secret key does not match"):
        call_command("racecraft_import", "--from-bucket", drfc.endpoint, BUCKET, PREFIX,
                     "--owner", "alice", "--name", "x", stdout=io.StringIO())  # fmt: skip
    monkeypatch.delenv("AWS_SECRET_ACCESS_KEY")
    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # no terminal to ask on
    with pytest.raises(CommandError, match="set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY"):
        call_command("racecraft_import", "--from-bucket", drfc.endpoint, BUCKET, PREFIX,
                     "--owner", "alice", "--name", "x", stdout=io.StringIO())  # fmt: skip
    with pytest.raises(CommandError, match="either ARCHIVE or --from-bucket"):
        call_command("racecraft_import", "m.tar.gz", "--from-bucket", "a:1", "b", "c",
                     "--owner", "alice", "--name", "x")  # fmt: skip
    with pytest.raises(CommandError, match="unrecognized arguments"):
        call_command("racecraft_import", "--from-bucket", drfc.endpoint, BUCKET, PREFIX,
                     "--owner", "alice", "--name", "x", "--secret-key", "s")  # fmt: skip


# ------------------------------------------------------------------------------ the import page
@pytest.fixture
def alice_client(alice) -> Client:
    client = Client()
    client.force_login(alice)
    return client


def form(drfc: Drfc, **overrides: object) -> dict:
    fields = {"name": "web-drfc", "description": "", **drfc.kwargs(), **overrides}
    fields.pop("secure")  # an unticked box is not sent
    return fields


def test_the_import_page_offers_the_bucket(alice_client) -> None:
    page = alice_client.get("/models/import/").content.decode()
    assert "From a DeepRacer-for-Cloud bucket" in page
    assert 'action="/models/import/bucket/"' in page
    assert 'type="password" name="secret_key"' in page


@pytest.mark.slow
def test_the_page_imports_from_a_bucket_through_the_worker_path(
    drfc, alice, alice_client, ppo_discrete, caplog
) -> None:
    caplog.set_level(logging.DEBUG)
    response = alice_client.post("/models/import/bucket/", form(drfc))
    assert response.status_code == 302, response.content.decode()[-3000:]
    assert "?task=" in response["Location"]
    page = alice_client.get(response["Location"]).content.decode()
    assert "data-background-poll=" in page
    # As an upload: the packed model waits in the store and its task in the queue.
    (upload,) = get_store().list(background.UPLOADS)
    assert any(upload.encode() in value for _, value in redis_values())  # the queued task
    assert not RacingModel.objects.filter(name="web-drfc").exists()
    assert_keys_nowhere(drfc, caplog, page)
    answer = background.model_import_run(  # the worker's side, run here
        owner_id=alice.pk, name="web-drfc", description="", upload_key=upload
    )
    assert answer["ok"] is True, answer
    model = RacingModel.objects.get(owner=alice, name="web-drfc")
    assert model.imported and get_store().list(background.UPLOADS) == []
    assert_drives_as(model, ppo_discrete)
    assert_keys_nowhere(drfc, caplog)


def test_a_refused_bucket_shows_on_its_field_and_never_the_keys(drfc, alice_client, caplog) -> None:
    caplog.set_level(logging.DEBUG)
    wrong = form(drfc, secret_key="not-the-secret-but-secret-too")
    response = alice_client.post("/models/import/bucket/", wrong)
    page = response.content.decode()
    assert response.status_code == 400
    assert "Access denied: the secret key does not match the access key" in page
    assert 'id="field-secret_key"' in page and "not-the-secret-but-secret-too" not in page
    assert get_store().list(background.UPLOADS) == []
    assert_keys_nowhere(drfc, caplog, page)


def test_a_failed_request_reports_no_key(drfc, alice, monkeypatch, caplog) -> None:
    """An unexpected failure mid-read: Django's error report (what a 500 mails to the admins)
    shows neither key, from the POST nor from any frame's variables."""
    from django.views.debug import ExceptionReporter

    from training.storage import s3

    def broken(*args: object) -> bytes:
        raise RuntimeError("the disk caught fire")

    monkeypatch.setattr(s3, "_read_object", broken)
    reports: list[str] = []

    def report(sender: object, request, **kwargs: object) -> None:
        import sys

        reporter = ExceptionReporter(request, *sys.exc_info())
        reports.extend([reporter.get_traceback_text(), reporter.get_traceback_html()])

    got_request_exception.connect(report)
    try:
        client = Client(raise_request_exception=False)
        client.force_login(alice)
        caplog.set_level(logging.DEBUG)
        response = client.post("/models/import/bucket/", form(drfc))
    finally:
        got_request_exception.disconnect(report)
    assert response.status_code == 500
    assert reports and "the disk caught fire" in reports[0]
    assert "secret_key" in reports[0]  # the POST's field is named, its value hidden
    assert_keys_nowhere(drfc, caplog, *reports)
