"""A small S3 reader for someone else's bucket, over the guarded outbound client
(:mod:`training.storage.outbound`): the bucket's region, a folder's listing (ListObjectsV2,
one level) and an object's bytes, signed with AWS Signature Version 4, path-style
(``http://host:port/bucket/key``), as MinIO and DeepRacer-for-Cloud's S3 take it.

It reads only what it is asked for, with the session's bounds; nothing the server sends is
ever put in an exception: an S3 error's code is turned into :class:`S3Refusal` only when it is
one of :data:`KNOWN_CODES`, and every other answer that is not S3's (HTML, a redirect, a
truncated or oversized body, a stalled socket) is an :class:`~training.storage.outbound.
OutboundError`.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import hmac
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from typing import Protocol
from urllib.parse import quote

from training.storage.outbound import Endpoint, OutboundError, OutboundSession

KNOWN_CODES = frozenset(
    {"InvalidAccessKeyId", "SignatureDoesNotMatch", "AccessDenied", "AllAccessDisabled",
     "AccountProblem", "NoSuchBucket", "InvalidBucketName", "NoSuchKey"}
)  # fmt: skip
"""S3 error codes that become our own sentence; any other error is a failure to reach."""
ERROR_BODY_BYTES = 64 * 1024
"""The most of an error's body read (S3's are a few hundred bytes)."""
LISTING_BODY_BYTES = 4 << 20
"""The most of one listing page read: 1,000 keys of up to 1,024 bytes, and their sizes."""
_EMPTY_SHA256 = hashlib.sha256(b"").hexdigest()
_DEFAULT_REGION = "us-east-1"


class S3Refusal(Exception):
    """The server answered one of :data:`KNOWN_CODES` (``code``)."""

    def __init__(self, code: str) -> None:
        super().__init__(code)
        self.code = code


class Keys(Protocol):
    """The keys, in an object whose ``repr`` leaves them out (a
    :class:`~training.storage.base.BucketAccess`), so no traceback's locals show them."""

    access_key: str
    secret_key: str


class ForeignBucket:
    """One bucket read through ``session`` with ``keys``; ``region`` empty: asked of the
    server first (GetBucketLocation, as the minio SDK does)."""

    def __init__(self, session: OutboundSession, bucket: str, keys: Keys, region: str = "") -> None:
        self._session = session
        self._bucket = bucket
        self._keys = keys
        self._region = region

    def __repr__(self) -> str:  # never the keys
        return f"ForeignBucket({self._session.endpoint}/{self._bucket})"

    def region(self) -> str:
        if not self._region:
            try:
                body = self._get(f"/{_path(self._bucket)}", {"location": ""}, ERROR_BODY_BYTES,
                                 region=_DEFAULT_REGION)  # fmt: skip
            except S3Refusal as refusal:
                if refusal.code != "AccessDenied":  # not allowed to ask: the default region
                    raise
                self._region = _DEFAULT_REGION
            else:
                root = _xml(body)
                if _local(root.tag) != "LocationConstraint":
                    raise OutboundError("not an S3 answer")
                self._region = (root.text or "").strip() or _DEFAULT_REGION
                if self._region == "EU":  # S3's old name for eu-west-1
                    self._region = "eu-west-1"
        return self._region

    def list_folder(self, prefix: str) -> Iterator[tuple[str, int]]:
        """``(key, size)`` of the objects right in ``prefix`` (a ``/``-ended folder, or ``""``
        for the top; sub-folders are skipped), page by page: the caller stops when it has
        enough; the session's request count stops a listing that never ends."""
        token = ""
        while True:
            query = {"list-type": "2", "delimiter": "/", "prefix": prefix, "max-keys": "1000"}
            if token:
                query["continuation-token"] = token
            root = _xml(self._get(f"/{_path(self._bucket)}", query, LISTING_BODY_BYTES))
            if _local(root.tag) != "ListBucketResult":
                raise OutboundError("not an S3 listing")
            truncated = "false"
            for child in root:
                name = _local(child.tag)
                if name == "Contents":
                    key, size = _text(child, "Key"), _text(child, "Size")
                    if not key.startswith(prefix) or not size.isdigit():
                        raise OutboundError("not an S3 listing")
                    yield key, int(size)
                elif name == "IsTruncated":
                    truncated = (child.text or "").strip().lower()
                elif name == "NextContinuationToken":
                    token = (child.text or "").strip()
            if truncated != "true":
                return
            if not token:
                raise OutboundError("a truncated listing without a token")

    def read(self, key: str, size: int) -> bytes:
        """The object's bytes; it may hold at most ``size`` (its listed size)."""
        body = self._get(f"/{_path(self._bucket)}/{_path(key)}", {}, size)
        if len(body) != size:
            raise OutboundError("an object not of its listed size")
        return body

    def _get(self, path: str, query: dict[str, str], max_bytes: int, *,
             region: str | None = None) -> bytes:  # fmt: skip
        region = region or self.region()
        canonical_query = "&".join(f"{_quote(k)}={_quote(v)}" for k, v in sorted(query.items()))
        headers = _signed_headers(
            "GET", self._session.endpoint, path, canonical_query, region, self._keys
        )
        target = f"{path}?{canonical_query}" if canonical_query else path
        # An error's body is read within its own bound, whatever the caller's.
        response = self._session.request(
            "GET", target, headers, max_bytes=max(max_bytes, ERROR_BODY_BYTES)
        )
        if response.status == 200:
            if len(response.body) > max_bytes:
                raise OutboundError(f"body over {max_bytes} bytes (200)")
            return response.body
        raise _refusal(response.body)


def _refusal(body: bytes) -> Exception:
    """An S3 error answer as :class:`S3Refusal` when its code is a known one; anything else
    (another code, no S3 error at all) as a failure to reach."""
    try:
        root = _xml(body)
    except OutboundError:
        return OutboundError("an error that is not S3's")
    code = _text(root, "Code") if _local(root.tag) == "Error" else ""
    if code in KNOWN_CODES:
        return S3Refusal(code)
    return OutboundError("an S3 error of another kind" if code else "an error that is not S3's")


def _xml(body: bytes) -> ET.Element:
    # No document type, so no entity of any kind; the body is already bounded.
    if b"<!DOCTYPE" in body.upper() or b"<!ENTITY" in body.upper():
        raise OutboundError("not an S3 answer")
    try:
        return ET.fromstring(body)
    except ET.ParseError:
        raise OutboundError("not an S3 answer") from None


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _text(element: ET.Element, name: str) -> str:
    for child in element:
        if _local(child.tag) == name:
            return (child.text or "").strip()
    return ""


def _quote(text: str) -> str:
    return quote(text, safe="-_.~")


def _path(key: str) -> str:
    return quote(key, safe="-_.~/")


def _signed_headers(
    method: str,
    endpoint: Endpoint,
    path: str,
    canonical_query: str,
    region: str,
    keys: Keys,
) -> dict[str, str]:
    """The headers of an AWS Signature Version 4 request with an empty body."""
    now = dt.datetime.now(dt.UTC)
    stamp, day = now.strftime("%Y%m%dT%H%M%SZ"), now.strftime("%Y%m%d")
    headers = {"host": endpoint.netloc, "x-amz-content-sha256": _EMPTY_SHA256,
               "x-amz-date": stamp}  # fmt: skip
    signed = ";".join(sorted(headers))
    canonical = "\n".join([
        method, path, canonical_query,
        "".join(f"{name}:{headers[name]}\n" for name in sorted(headers)),
        signed, _EMPTY_SHA256,
    ])  # fmt: skip
    scope = f"{day}/{region}/s3/aws4_request"
    to_sign = "\n".join(
        ["AWS4-HMAC-SHA256", stamp, scope, hashlib.sha256(canonical.encode()).hexdigest()]
    )
    signature = hmac.new(_signing_key(keys, day, region), to_sign.encode(),
                         hashlib.sha256).hexdigest()  # fmt: skip
    authorization = (f"AWS4-HMAC-SHA256 Credential={keys.access_key}/{scope}, "
                     f"SignedHeaders={signed}, Signature={signature}")  # fmt: skip
    return {"x-amz-content-sha256": _EMPTY_SHA256, "x-amz-date": stamp,
            "Authorization": authorization}  # fmt: skip


def _signing_key(keys: Keys, day: str, region: str) -> bytes:
    key = hmac.new(f"AWS4{keys.secret_key}".encode(), day.encode(), hashlib.sha256).digest()
    for part in (region, "s3", "aws4_request"):
        key = hmac.new(key, part.encode(), hashlib.sha256).digest()
    return key
