"""Home page, track gallery and track previews, over the real track catalogue."""

from __future__ import annotations

import io
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from django.contrib.staticfiles import finders
from django.template.defaultfilters import floatformat
from django.test import Client
from pytest_django.fixtures import Settings as SettingsWrapper

from console import tracks
from racing.tracks import TrackCatalog, TrackInfo, import_track

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def oval_track_npy(*, rx: float = 6.0, ry: float = 3.5, width: float = 1.06) -> bytes:
    """A closed oval in DeepRacer's format (centre, inner, outer x/y per row), as .npy bytes."""
    angles = np.linspace(0.0, 2 * np.pi, 81)
    cos, sin = np.cos(angles), np.sin(angles)
    half = width / 2
    rows = np.column_stack(
        [rx * cos, ry * sin, (rx - half) * cos, (ry - half) * sin, (rx + half) * cos,
         (ry + half) * sin]
    )  # fmt: skip
    rows[-1] = rows[0]  # a closed loop repeats its first row
    buffer = io.BytesIO()
    np.save(buffer, rows)
    return buffer.getvalue()


@pytest.fixture
def imported_track(settings: SettingsWrapper, tmp_path: Path) -> Iterator[TrackInfo]:
    """A user-imported oval "Test Oval" in a fresh RACECRAFT_TRACKS_DIR."""
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    track_id = f"test_oval_{uuid.uuid4().hex[:8]}"
    yield import_track(
        oval_track_npy(), track_id=track_id, dest_dir=tmp_path / "tracks", name="Test Oval"
    )
    tracks.preview_cache_clear()


def test_home_page_has_navigation(client: Client) -> None:
    response = client.get("/")
    assert response.status_code == 200
    html = response.content.decode()
    for label, href in (("Models", "/models/"), ("Tracks", "/tracks/"), ("League", "/league/")):
        assert f'href="{href}"' in html
        assert f">{label}</a>" in html
    assert "/static/css/app.css" in html


def test_stylesheet_is_found_without_collectstatic() -> None:
    assert finders.find("css/app.css") is not None


def test_gallery_lists_every_track(
    client: Client, settings: SettingsWrapper, imported_track: TrackInfo
) -> None:
    response = client.get("/tracks/")
    assert response.status_code == 200
    html = response.content.decode()
    every = TrackCatalog(extra_dirs=[settings.RACECRAFT_TRACKS_DIR]).list()
    assert imported_track.id in {info.id for info in every}
    for info in every:
        assert info.name in html
        assert f'src="/tracks/{info.id}.png"' in html
        assert f"{floatformat(info.length_m, 2)} m" in html
        assert f"{floatformat(info.width_m, 2)} m" in html
    assert f"{len(every)} track" in html
    assert "Imported" in html


def test_gallery_shows_direction_in_words(client: Client, imported_track: TrackInfo) -> None:
    html = client.get("/tracks/").content.decode()
    assert imported_track.direction in ("ccw", "cw", "open")
    assert tracks.DIRECTION_LABELS[imported_track.direction] in html


def test_builtin_tracks_need_no_import_folder(
    client: Client, settings: SettingsWrapper, tmp_path: Path
) -> None:
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "missing"
    response = client.get("/tracks/")
    assert response.status_code == 200
    for info in TrackCatalog().list():
        assert info.name in response.content.decode()


def test_preview_is_a_cacheable_png(client: Client, imported_track: TrackInfo) -> None:
    response = client.get(f"/tracks/{imported_track.id}.png")
    assert response.status_code == 200
    assert response["Content-Type"] == "image/png"
    assert response.content.startswith(PNG_SIGNATURE)
    assert response["ETag"].startswith('"')
    assert "max-age=3600" in response["Cache-Control"]
    assert "public" in response["Cache-Control"]

    again = client.get(
        f"/tracks/{imported_track.id}.png", headers={"if-none-match": response["ETag"]}
    )
    assert again.status_code == 304
    assert again["ETag"] == response["ETag"]


def test_preview_is_rendered_once_per_process(
    client: Client, imported_track: TrackInfo, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[str] = []
    real_render = tracks.render_preview_png

    def counting_render(track: object, width_px: int = 480) -> bytes:
        calls.append(imported_track.id)
        return real_render(track, width_px=width_px)

    monkeypatch.setattr(tracks, "render_preview_png", counting_render)
    first = client.get(f"/tracks/{imported_track.id}.png")
    second = client.get(f"/tracks/{imported_track.id}.png")
    assert first.content == second.content
    assert calls == [imported_track.id]


def test_preview_of_unknown_track_is_404(client: Client) -> None:
    assert client.get("/tracks/no_such_track_here.png").status_code == 404
    assert client.get("/tracks/not%20an%20id.png").status_code == 404


def test_admin_is_enabled(client: Client) -> None:
    response = client.get("/admin/")
    assert response.status_code == 302
    assert response["Location"].startswith("/admin/login/")


@pytest.mark.django_db
def test_admin_index_for_a_superuser(admin_client: Client) -> None:
    response = admin_client.get("/admin/")
    assert response.status_code == 200
    assert "Site administration" in response.content.decode()
