"""Byte ranges for stored videos: what a browser asks for to seek."""

from __future__ import annotations

import pytest
from django.test import RequestFactory

from training.http import media_response

DATA = bytes(range(100))


def ask(range_header: str | None):
    headers = {"HTTP_RANGE": range_header} if range_header else {}
    request = RequestFactory().get("/video.mp4", **headers)
    return media_response(request, DATA, content_type="video/mp4", filename="v.mp4")


def test_whole_file_says_ranges_are_accepted():
    response = ask(None)
    assert response.status_code == 200 and b"".join(response.streaming_content) == DATA
    assert response["Content-Length"] == "100"
    assert response["Accept-Ranges"] == "bytes"
    assert response["Content-Disposition"] == 'inline; filename="v.mp4"'


@pytest.mark.parametrize(
    "header, start, end",
    [("bytes=0-9", 0, 9), ("bytes=90-", 90, 99), ("bytes=-5", 95, 99), ("bytes=50-500", 50, 99)],
)
def test_one_range(header, start, end):
    response = ask(header)
    assert response.status_code == 206
    assert response.content == DATA[start : end + 1]
    assert response["Content-Range"] == f"bytes {start}-{end}/100"


@pytest.mark.parametrize("header", ["bytes=100-", "bytes=50-10"])
def test_unsatisfiable_range(header):
    response = ask(header)
    assert response.status_code == 416 and response["Content-Range"] == "bytes */100"


@pytest.mark.parametrize("header", ["bytes=0-1,5-6", "items=0-1", "bytes=-"])
def test_other_headers_get_the_whole_file(header):
    response = ask(header)
    assert response.status_code == 200 and b"".join(response.streaming_content) == DATA


def test_large_media_is_read_a_range_at_a_time(monkeypatch):
    import training.http as http

    monkeypatch.setattr(http, "CHUNK_BYTES", 16)
    monkeypatch.setattr(http, "MAX_RANGE_BYTES", 32)
    reads = []

    def read(start: int, length: int) -> bytes:
        reads.append((start, length))
        return DATA[start : start + length]

    media = http.Media(len(DATA), read)
    request = RequestFactory().get("/video.mp4", HTTP_RANGE="bytes=10-")
    response = http.media_response(request, media, content_type="video/mp4", filename="v.mp4")
    assert response.status_code == 206 and response["Content-Range"] == "bytes 10-41/100"
    assert response.content == DATA[10:42] and reads == [(10, 32)]  # capped: never the whole
    reads.clear()
    whole = http.media_response(RequestFactory().get("/v"), media, content_type="video/mp4",
                                filename="v.mp4")  # fmt: skip
    assert b"".join(whole.streaming_content) == DATA
    assert max(length for _, length in reads) == 16  # streamed in chunks
