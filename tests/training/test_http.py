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
    assert response.status_code == 200 and response.content == DATA
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
    assert response.status_code == 200 and response.content == DATA
