"""Importing a model straight from a DeepRacer-for-Cloud bucket (MinIO or S3): the model's
prefix is read (:func:`training.storage.read_model_folder`: only the files an import needs,
:func:`training.interchange.deepracer.model_folder_plan`, within the upload's own limits), packed
as the tar a DeepRacer-for-Cloud folder upload is, and imported as any upload is
(:func:`~training.services.model_imports.model_import`: all validation in one place).

The keys are used for this one read and never kept: not in the database, the store, a task's
arguments nor a log line; they travel in a :class:`~training.storage.BucketAccess`, whose
``repr`` leaves them out, and the functions holding them are marked for Django's error reports
(``sensitive_variables``). Every failure is one :class:`ServiceError` on the field to fix.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import redis
from django.conf import settings
from django.views.decorators.debug import sensitive_variables

from training.errors import ServiceError
from training.interchange.archive import ArchiveError, ImportLimits
from training.interchange.deepracer import model_folder_plan
from training.interchange.tarball import deterministic_tar
from training.models import RacingModel
from training.services.background import model_import_start
from training.services.checks import check_model_quota, check_name
from training.services.model_imports import model_import
from training.storage import BucketAccess, BucketError, read_model_folder
from training.storage.outbound import AllowList, OutboundPolicy

log = logging.getLogger(__name__)

#: Seconds to connect to the bucket's server.
BUCKET_TIMEOUT_S = 10.0
#: Seconds one import may spend reading the bucket in all (every request and byte): the web
#: request waits for it, so a server that answers slowly or never ends is cut off here.
BUCKET_DEADLINE_S = 120.0
#: Requests one import may send: the region, three folders' listings, a handful of files.
BUCKET_MAX_REQUESTS = 100
_TAR_OVERHEAD = 3 * 512  # a member's header, a long name's PAX header, padding (bytes)
_MAX_PLANNED = 64  # members of a packed model: a handful of files and a checkpoint's shards

_FIELDS = {
    "endpoint": "endpoint",
    "unreachable": "endpoint",
    "refused": "endpoint",
    "access_key": "access_key",
    "secret_key": "secret_key",
    "denied": "access_key",
    "bucket": "bucket",
    "prefix": "prefix",
    "too_big": "prefix",
}


@sensitive_variables()
def model_import_from_bucket(
    *,
    owner,
    name: str,
    endpoint: str,
    bucket: str,
    prefix: str,
    access_key: str,
    secret_key: str,
    secure: bool,
    region: str = "",
    description: str = "",
) -> RacingModel:
    """A model from a DeepRacer-for-Cloud model prefix (``model/model_metadata.json``,
    ``model/model_<n>.pb`` or TensorFlow checkpoints, ``ip/hyperparameters.json``,
    ``reward_function.py``, ``training_params*.yaml``) in ``bucket`` at ``endpoint``
    (``host:port``; an ``http://``/``https://`` in front decides ``secure``), imported in this
    process as :func:`~training.services.model_imports.model_import` imports an upload.
    Raises :class:`ServiceError` on the field to fix (``endpoint``, ``access_key``,
    ``secret_key``, ``bucket``, ``prefix``, ``archive``, ``name``). The command line's way
    in: the operator's own, so without the per-user slot of the web's."""
    check_name(owner, name)
    check_model_quota(owner)
    archive = bucket_model_archive(
        endpoint=endpoint, bucket=bucket, prefix=prefix, access_key=access_key,
        secret_key=secret_key, secure=secure, region=region,
    )  # fmt: skip
    return model_import(owner=owner, name=name, upload=archive, description=description)


@sensitive_variables()
def model_import_from_bucket_start(
    *,
    owner,
    name: str,
    endpoint: str,
    bucket: str,
    prefix: str,
    access_key: str,
    secret_key: str,
    secure: bool,
    region: str = "",
    description: str = "",
) -> str:
    """For the web: read the model prefix here (bounded: the upload's size limits, short
    timeouts), then store it and queue its import on a worker exactly as an upload is
    (:func:`~training.services.background.model_import_start`); returns the task id. Only
    the packed files leave this function: the keys stay in it. One such read at a time per
    user (:func:`bucket_read_slot`). Raises :class:`ServiceError`."""
    check_name(owner, name)
    check_model_quota(owner)
    with bucket_read_slot(owner):
        archive = bucket_model_archive(
            endpoint=endpoint, bucket=bucket, prefix=prefix, access_key=access_key,
            secret_key=secret_key, secure=secure, region=region,
        )  # fmt: skip
    return model_import_start(owner=owner, name=name, description=description, data=archive)


@sensitive_variables()
def bucket_model_archive(
    *,
    endpoint: str,
    bucket: str,
    prefix: str,
    access_key: str,
    secret_key: str,
    secure: bool,
    region: str = "",
) -> bytes:
    """The files of the model prefix an import needs, as an uncompressed tar laid out as the
    prefix (the layout a DeepRacer-for-Cloud folder upload has). At most
    :class:`~training.interchange.archive.ImportLimits`' members and upload bytes are read.
    Raises :class:`ServiceError` saying what failed, on the field to fix."""
    access = BucketAccess(
        endpoint=endpoint.strip(),
        bucket=bucket.strip(),
        prefix=prefix.strip().strip("/"),
        access_key=access_key,
        secret_key=secret_key,
        secure=secure,
        region=region.strip(),
    )
    limits = ImportLimits()
    plan: dict[str, str] = {}

    def choose(sizes, read) -> list[str]:
        plan.update(model_folder_plan(sizes, read))
        return list(plan.values())

    try:
        files = read_model_folder(
            access,
            choose,
            max_files=limits.max_members,
            max_bytes=limits.max_upload_bytes - _TAR_OVERHEAD * _MAX_PLANNED,
            policy=outbound_policy(),
        )
    except ArchiveError as exc:
        raise ServiceError(f"no DeepRacer model at {access.url}: {exc}", field="prefix") from None
    except BucketError as exc:
        log.info("reading a model from a bucket failed: %s", exc)  # names no key
        raise _bucket_refusal(access, exc) from None
    archive = deterministic_tar({member: files[path] for member, path in plan.items()})
    if len(archive) > limits.max_upload_bytes:
        raise ServiceError(
            f"the model at {access.url} is larger than "
            f"{limits.max_upload_bytes // 2**20} MB, the most imported",
            field="prefix",
        )
    return archive


class BucketImportBusy(ServiceError):
    """The user already has a read from a bucket under way."""


BUCKET_IMPORT_BUSY = (
    "an import from a bucket is already running for you: wait until it ends, then try again"
)
_SLOT_RELEASE = (
    "if redis.call('get', KEYS[1]) == ARGV[1] then return redis.call('del', KEYS[1]) end"
)


def outbound_policy() -> OutboundPolicy:
    """The bounds of one import's read (:data:`BUCKET_DEADLINE_S`...) and the addresses the
    operator allows besides public ones (settings.RACECRAFT_OUTBOUND_ALLOW)."""
    return OutboundPolicy(
        allow=AllowList.parse(settings.RACECRAFT_OUTBOUND_ALLOW),
        connect_timeout_s=BUCKET_TIMEOUT_S,
        read_timeout_s=3 * BUCKET_TIMEOUT_S,
        deadline_s=BUCKET_DEADLINE_S,
        max_requests=BUCKET_MAX_REQUESTS,
    )


@contextmanager
def bucket_read_slot(owner) -> Iterator[None]:
    """The user's one slot for reading a bucket, held in Redis (every web process sees it)
    while the body runs, and at most :data:`BUCKET_DEADLINE_S` plus a minute should the
    process die holding it. Raises :class:`BucketImportBusy` when it is taken, a
    :class:`ServiceError` when Redis cannot be reached."""
    client = redis.Redis.from_url(settings.REDIS_URL)
    key = f"{settings.REDIS_PREFIX}racecraft:bucket-import:{owner.pk}"
    token = uuid.uuid4().hex
    try:
        taken = client.set(key, token, nx=True, ex=int(BUCKET_DEADLINE_S) + 60)
    except redis.RedisError:
        client.close()
        raise ServiceError("imports cannot start right now; try again in a minute") from None
    if not taken:
        client.close()
        raise BucketImportBusy(BUCKET_IMPORT_BUSY)
    try:
        yield
    finally:
        try:
            client.eval(_SLOT_RELEASE, 1, key, token)
        except redis.RedisError:
            log.warning("the bucket import slot of user %s was not released", owner.pk)
        finally:
            client.close()


def _bucket_refusal(access: BucketAccess, exc: BucketError) -> ServiceError:
    scheme = "https" if access.secure else "http"
    where = access.endpoint if "://" in access.endpoint else f"{scheme}://{access.endpoint}"
    words = {
        "endpoint": f"the endpoint must be host:port (minio.lan:9000), not {access.endpoint!r}",
        "unreachable": unreachable(where),
        "access_key": "access denied: the server does not know this access key",
        "secret_key": "access denied: the secret key does not match the access key",
        "denied": f"access denied: these keys may not read {access.url}",
        "bucket": f"there is no bucket {access.bucket!r} at {where}",
        "prefix": f"{access.prefix!r} is not a folder name (letters, digits, -, _, . and /)",
        "too_big": f"{exc}, the most imported",
    }
    message = words.get(exc.reason, unreachable(where))
    return ServiceError(message, field=_FIELDS.get(exc.reason, "endpoint"))


def unreachable(where: str) -> str:
    """The one sentence for every failure to reach an S3 server at ``where`` (the address the
    user gave): a refused address, a closed port, a redirect, an answer that is not S3's, too
    big or too slow. Nothing the server sent is in it, so no answer tells what listens."""
    return f"cannot reach an S3 server at {where}: check the address, the port and HTTPS"
