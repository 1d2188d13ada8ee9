"""Reads of the track catalogue for the web UI, and the cached preview images.

The tracks themselves live in ``racing`` (built-in files) and in RACECRAFT_TRACKS_DIR
(files a user imported); this module only adapts them for views.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass

from racing.preview import render_preview_png
from racing.tracks import TrackInfo, UnknownTrackError
from training.services import track_catalog

__all__ = [
    "PREVIEW_WIDTH_PX",
    "TrackPreview",
    "TrackRow",
    "UnknownTrackError",
    "preview_cache_clear",
    "track_catalog",
    "track_preview",
    "track_rows",
]

PREVIEW_WIDTH_PX = 480
"""Width of a gallery preview image, pixels."""

DIRECTION_LABELS = {"ccw": "Counter-clockwise", "cw": "Clockwise", "open": "Open (one way)"}


@dataclass(frozen=True, slots=True)
class TrackRow:
    """One track as the gallery shows it."""

    info: TrackInfo
    direction_label: str


@dataclass(frozen=True, slots=True)
class TrackPreview:
    """A rendered preview: PNG bytes and their strong ETag (without quotes)."""

    png: bytes
    etag: str


_preview_cache: dict[str, TrackPreview] = {}
_preview_lock = threading.Lock()


def track_rows() -> list[TrackRow]:
    """Every track, in the catalogue's order."""
    return [
        TrackRow(info=info, direction_label=DIRECTION_LABELS.get(info.direction, info.direction))
        for info in track_catalog().list()
    ]


def track_preview(track_id: str) -> TrackPreview:
    """The preview of ``track_id``, rendered once per process.

    Raises UnknownTrackError when there is no such track.
    """
    cached = _preview_cache.get(track_id)
    if cached is not None:
        return cached
    # Rendering takes tens of milliseconds; the lock keeps a burst of gallery requests from
    # rendering the same track several times.
    with _preview_lock:
        cached = _preview_cache.get(track_id)
        if cached is None:
            track = track_catalog().load(track_id)
            png = render_preview_png(track, width_px=PREVIEW_WIDTH_PX)
            cached = TrackPreview(png=png, etag=hashlib.sha256(png).hexdigest()[:32])
            _preview_cache[track_id] = cached
    return cached


def preview_cache_clear() -> None:
    """Forget every rendered preview (e.g. after a track was imported again)."""
    with _preview_lock:
        _preview_cache.clear()
