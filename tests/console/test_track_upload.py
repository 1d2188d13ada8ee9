"""Importing a track file on the Tracks page: preview first, the same checks as
``manage.py import_track``, a clear error and nothing written for a bad file."""

from __future__ import annotations

import base64
import io
import re

import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from racing.tracks import TrackCatalog

pytestmark = pytest.mark.django_db


@pytest.fixture
def tracks_dir(tmp_path, settings):
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    return settings.RACECRAFT_TRACKS_DIR


def _npy() -> bytes:
    track = TrackCatalog().load("racecraft_oval")
    buffer = io.BytesIO()
    np.save(buffer, track.to_array())
    return buffer.getvalue()


def _upload(data: bytes, name: str = "my oval.npy") -> SimpleUploadedFile:
    return SimpleUploadedFile(name, data, "application/octet-stream")


def test_preview_then_import(alice_client, tracks_dir) -> None:
    response = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "preview": "1"})
    page = response.content.decode()
    assert response.status_code == 200 and 'id="track-upload-preview"' in page
    assert "data:image/png;base64," in page and "my_oval" in page
    assert not list(tracks_dir.glob("*.npy"))  # a preview writes nothing
    carried = re.search(r'name="data" value="([^"]+)"', page)[1]
    assert base64.b64decode(carried) == _npy()
    response = alice_client.post(
        "/tracks/import/",
        {"data": carried, "filename": "my oval.npy", "track_id": "my_oval", "name": "My oval",
         "import": "1"},
    )  # fmt: skip
    assert response.status_code == 302 and response["Location"] == "/tracks/#track-my_oval"
    gallery = alice_client.get("/tracks/").content.decode()
    assert 'id="track-my_oval"' in gallery and "My oval" in gallery
    again = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "track_id": "my_oval",
                                                  "import": "1"})  # fmt: skip
    assert again.status_code == 400 and "exists already" in again.content.decode()


@pytest.mark.parametrize(
    ("data", "track_id", "text"),
    [
        (b"", "", "Choose a DeepRacer .npy track file"),
        (b"not a numpy file at all", "junk", ""),
        (None, "racecraft_oval", "exists already"),
        (None, "bad id!", "track id"),
    ],
)
def test_bad_uploads_are_refused_and_nothing_is_written(alice_client, tracks_dir, data,
                                                        track_id, text) -> None:  # fmt: skip
    body = {"track_id": track_id, "import": "1"}
    if data != b"":
        body["file"] = _upload(_npy() if data is None else data)
    response = alice_client.post("/tracks/import/", body)
    page = response.content.decode()
    assert response.status_code == 400 and ("form-error" in page or "field-error" in page)
    assert text in page
    assert not list(tracks_dir.glob("*.npy")) and not list(tracks_dir.glob("*.json"))
    assert not [p for p in tracks_dir.glob(".upload-*")]  # no scratch left behind


def test_importing_needs_an_account(client, tracks_dir) -> None:
    response = client.post("/tracks/import/", {"file": _upload(_npy()), "import": "1"})
    assert response.status_code == 302 and "/accounts/login/" in response["Location"]
    assert "Log in</a> to import a track file" in client.get("/tracks/").content.decode()
