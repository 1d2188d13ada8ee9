"""HTTP answers for stored media: byte ranges, which browsers need to seek in a video, read
from the store a range at a time (a request never loads the whole object into memory)."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from django.http import HttpRequest, HttpResponse, StreamingHttpResponse

_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")
CHUNK_BYTES = 1 << 20
"""What one read from the store returns while a whole file streams, bytes."""
MAX_RANGE_BYTES = 4 << 20
"""The most one range answer carries, bytes: an open range ("bytes=0-") gets this much and the
browser asks for the rest, as RFC 9110 allows."""


@dataclass(frozen=True)
class Media:
    """A stored object: its ``size`` in bytes and ``read(start, length) -> bytes``."""

    size: int
    read: Callable[[int, int], bytes]

    @classmethod
    def of_bytes(cls, data: bytes) -> Media:
        return cls(len(data), lambda start, length: data[start : start + length])


def _chunks(media: Media) -> Iterator[bytes]:
    for start in range(0, media.size, CHUNK_BYTES):
        yield media.read(start, min(CHUNK_BYTES, media.size - start))


def media_response(
    request: HttpRequest, media: Media | bytes, *, content_type: str, filename: str
) -> HttpResponse | StreamingHttpResponse:
    """The whole file (200, streamed in chunks), one requested byte range (206, at most
    ``MAX_RANGE_BYTES``), or 416 for a range outside it.

    Only single ranges are served; a multi-range or malformed header gets the whole file, as
    RFC 9110 allows.
    """
    if isinstance(media, bytes | bytearray):
        media = Media.of_bytes(bytes(media))
    size = media.size
    header = request.headers.get("Range", "").strip()
    match = _RANGE.match(header) if header else None
    response: HttpResponse | StreamingHttpResponse
    if match and (match.group(1) or match.group(2)):
        first, last = match.group(1), match.group(2)
        if first:
            start = int(first)
            end = min(int(last), size - 1) if last else size - 1
        else:  # the last N bytes
            start = max(0, size - int(last))
            end = size - 1
        if start >= size or end < start:
            response = HttpResponse(status=416)
            response["Content-Range"] = f"bytes */{size}"
            return response
        end = min(end, start + MAX_RANGE_BYTES - 1)
        response = HttpResponse(
            media.read(start, end - start + 1), status=206, content_type=content_type
        )
        response["Content-Range"] = f"bytes {start}-{end}/{size}"
    else:
        response = StreamingHttpResponse(_chunks(media), content_type=content_type)
        response["Content-Length"] = str(size)
    response["Accept-Ranges"] = "bytes"
    response["Content-Disposition"] = f'inline; filename="{filename}"'
    return response
