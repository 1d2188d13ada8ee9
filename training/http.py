"""HTTP answers for stored media: byte ranges, which browsers need to seek in a video."""

from __future__ import annotations

import re

from django.http import HttpRequest, HttpResponse

_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


def media_response(
    request: HttpRequest, data: bytes, *, content_type: str, filename: str
) -> HttpResponse:
    """The whole file (200), one requested byte range (206), or 416 for a range outside it.

    Only single ranges are served; a multi-range or malformed header gets the whole file, as
    RFC 9110 allows.
    """
    size = len(data)
    header = request.headers.get("Range", "").strip()
    match = _RANGE.match(header) if header else None
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
        response = HttpResponse(data[start : end + 1], status=206, content_type=content_type)
        response["Content-Range"] = f"bytes {start}-{end}/{size}"
    else:
        response = HttpResponse(data, content_type=content_type)
    response["Accept-Ranges"] = "bytes"
    response["Content-Disposition"] = f'inline; filename="{filename}"'
    return response
