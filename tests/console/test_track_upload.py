"""Importing a track file on the Tracks page: preview first, the same checks as
``manage.py import_track``, a clear error and nothing written for a bad file."""

from __future__ import annotations

import base64
import io
import re
from pathlib import Path

import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from racing.tracks import DEEPRACER_DIR, MAX_TRACK_FILE_BYTES, TrackCatalog

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


def _kept_token(page: str) -> str:
    return re.search(r'name="kept" value="([^"]+)"', page)[1]


def test_preview_then_import(alice_client, tracks_dir) -> None:
    response = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "preview": "1"})
    page = response.content.decode()
    assert response.status_code == 200 and 'id="track-upload-preview"' in page
    assert "data:image/png;base64," in page and "my_oval" in page
    assert not list(tracks_dir.glob("*.npy"))  # a preview writes nothing
    assert 'id="carried-file">my oval.npy' in page
    response = alice_client.post(
        "/tracks/import/",
        {"kept": _kept_token(page), "track_id": "my_oval", "name": "My oval", "import": "1"},
    )
    assert response.status_code == 302 and response["Location"] == "/tracks/#track-my_oval"
    assert np.array_equal(np.load(tracks_dir / "my_oval.npy"), np.load(io.BytesIO(_npy())))
    gallery = alice_client.get("/tracks/").content.decode()
    assert 'id="track-my_oval"' in gallery and "My oval" in gallery
    again = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "track_id": "my_oval",
                                                  "import": "1"})  # fmt: skip
    assert again.status_code == 400 and "exists already" in again.content.decode()


def _near_the_limit() -> bytes:
    """A valid DeepRacer track file just under the limit (1,996,928 bytes): an N x 6 float64
    array (centre, inner and outer x,y) of 41,600 rows, an 8 x 5 m ellipse 1.1 m wide, closed
    (the last row repeats the first). Each of its 4,160 waypoints comes 10 times in a row (the
    validator drops repeats), which keeps the geometry checks to seconds; the bytes are what
    the size limits see."""
    t = np.repeat(np.linspace(0, 2 * np.pi, 4_160, endpoint=False), 10)[:-1]
    t = np.append(t, 0.0)
    centre = np.column_stack([8.0 * np.cos(t), 5.0 * np.sin(t)])
    normal = np.column_stack([5.0 * np.cos(t), 8.0 * np.sin(t)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    array = np.hstack([centre, centre - 0.55 * normal, centre + 0.55 * normal])
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def test_a_track_near_the_size_limit_imports_after_its_preview(
    alice_client, tracks_dir, settings
) -> None:
    """The issue: a valid track of 1.92 MB (of 1,024,000 bytes) previewed, then Import answered
    400: the page sent the file back as base64 in a field, and from 1,966,080 bytes of file
    (the limit is 2,000,000) that is over DATA_UPLOAD_MAX_MEMORY_SIZE (2.5 MiB)."""
    data = _near_the_limit()
    assert 1_966_080 < len(data) <= MAX_TRACK_FILE_BYTES
    assert len(base64.b64encode(data)) > settings.DATA_UPLOAD_MAX_MEMORY_SIZE  # the old way
    preview = alice_client.post("/tracks/import/", {"file": _upload(data, "ellipse.npy"),
                                                    "preview": "1"})  # fmt: skip
    page = preview.content.decode()
    assert preview.status_code == 200 and 'id="track-upload-preview"' in page
    assert len(page) < 500_000  # the page does not carry the file
    response = alice_client.post("/tracks/import/", {"kept": _kept_token(page), "import": "1"})
    assert response.status_code == 302, response.content.decode()[:2000]
    assert response["Location"] == "/tracks/#track-ellipse"
    info = TrackCatalog([tracks_dir]).info("ellipse")
    assert info.closed and info.length_m == pytest.approx(41.39, abs=0.05)
    # Imported once: the kept file is gone, so the same token imports nothing more.
    again = alice_client.post("/tracks/import/", {"kept": _kept_token(page), "track_id": "e2",
                                                  "import": "1"})  # fmt: skip
    assert again.status_code == 400 and "no longer kept" in again.content.decode()


def test_a_file_over_the_limit_is_refused_with_the_limit(alice_client, tracks_dir) -> None:
    data = _npy() + b"\0" * MAX_TRACK_FILE_BYTES
    response = alice_client.post("/tracks/import/", {"file": _upload(data), "preview": "1"})
    page = response.content.decode()
    assert response.status_code == 400
    assert f"a track file is at most {MAX_TRACK_FILE_BYTES:,}" in page
    assert "at most 2 MB" in alice_client.get("/tracks/").content.decode()  # the page says so
    assert not list(tracks_dir.glob("*.npy"))


def test_a_kept_file_is_its_owners_only(alice_client, charlie_client, tracks_dir) -> None:
    """Charlie cannot import the file Alice previewed, even with her token."""
    page = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "preview": "1"})
    token = _kept_token(page.content.decode())
    response = charlie_client.post("/tracks/import/", {"kept": token, "track_id": "stolen",
                                                       "import": "1"})  # fmt: skip
    assert response.status_code == 400 and "no longer kept" in response.content.decode()
    assert not list(tracks_dir.glob("*.npy"))
    # Alice's own later preview replaces the kept file: the first token is spent.
    second = alice_client.post("/tracks/import/", {"file": _upload(_npy(), "b.npy"),
                                                   "preview": "1"})  # fmt: skip
    assert _kept_token(second.content.decode()) != token
    stale = alice_client.post("/tracks/import/", {"kept": token, "import": "1"})
    assert stale.status_code == 400 and "choose it again" in stale.content.decode()


@pytest.mark.parametrize(
    ("data", "track_id", "text"),
    [
        (b"", "", "Choose a DeepRacer .npy track file"),
        (b"not a numpy file at all", "junk", ""),
        (None, "racecraft_oval", "is the id of a built-in track"),
        (None, "RACECRAFT_OVAL", "differs only in case from the built-in track"),
        (None, "Reinvent_Base", "differs only in case from the built-in track"),
        (None, "bad id!", "track id"),
        (DEEPRACER_DIR / "reinvent_base.npy", "my_copy", "track, built in as"),
    ],
)
def test_bad_uploads_are_refused_and_nothing_is_written(alice_client, tracks_dir, data,
                                                        track_id, text) -> None:  # fmt: skip
    body = {"track_id": track_id, "import": "1"}
    if data != b"":
        if isinstance(data, Path):
            data = data.read_bytes()
        body["file"] = _upload(_npy() if data is None else data)
    response = alice_client.post("/tracks/import/", body)
    page = response.content.decode()
    assert response.status_code == 400 and ("form-error" in page or "field-error" in page)
    assert text in page
    assert not list(tracks_dir.glob("*.npy")) and not list(tracks_dir.glob("*.json"))
    assert not [p for p in tracks_dir.glob(".upload-*")]  # no scratch left behind


def test_an_id_differing_only_in_case_from_an_imported_track_is_refused(
    alice_client, tracks_dir
) -> None:
    first = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "track_id": "My_Oval",
                                                  "import": "1"})  # fmt: skip
    assert first.status_code == 302
    again = alice_client.post("/tracks/import/", {"file": _upload(_npy()), "track_id": "my_oval",
                                                  "import": "1"})  # fmt: skip
    page = again.content.decode()
    assert again.status_code == 400
    assert "differs only in case from the track" in page and "My_Oval" in page
    assert sorted(p.name for p in tracks_dir.glob("*.npy")) == ["My_Oval.npy"]


def test_importing_needs_an_account(client, tracks_dir) -> None:
    response = client.post("/tracks/import/", {"file": _upload(_npy()), "import": "1"})
    assert response.status_code == 302 and "/accounts/login/" in response["Location"]
    assert "Log in</a> to import a track file" in client.get("/tracks/").content.decode()
