"""Reads of the track catalogue for the web UI, and the cached preview images.

The tracks themselves live in ``racing`` (built-in files) and in RACECRAFT_TRACKS_DIR
(files a user imported); this module only adapts them for views.
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from racing.conditions import IMAGE_FAMILIES, Conditions, ConditionsSpec, parameters
from racing.preview import (
    render_conditions_preview_png,
    render_preview_png,
    render_race_preview_png,
)
from racing.track import TrackError
from racing.tracks import TrackInfo, UnknownTrackError
from training.services import race_config, track_catalog

__all__ = [
    "PREVIEW_WIDTH_PX",
    "SOURCE_LABELS",
    "TrackFilter",
    "TrackPreview",
    "TrackRow",
    "UnknownTrackError",
    "conditions_preview",
    "conditions_samples",
    "preview_cache_clear",
    "race_preview",
    "track_catalog",
    "track_preview",
    "track_rows",
    "track_seasons",
]

PREVIEW_WIDTH_PX = 480
"""Width of a gallery preview image, pixels."""

DIRECTION_LABELS = {"ccw": "Counter-clockwise", "cw": "Clockwise", "open": "Open (one way)"}
SOURCE_LABELS = {"racecraft": "Racecraft", "deepracer": "DeepRacer", "imported": "Imported"}
NO_SEASON = "other"
"""The season filter's value for tracks whose season is not known."""


@dataclass(frozen=True, slots=True)
class TrackRow:
    """One track as the gallery shows it."""

    info: TrackInfo
    direction_label: str

    @property
    def season_label(self) -> str:
        return self.info.season or "Other"

    @property
    def search_text(self) -> str:
        """What the search box matches: the name and the id, lower case."""
        return f"{self.info.name} {self.info.id}".casefold()


@dataclass(frozen=True, slots=True)
class TrackFilter:
    """The gallery's and the pickers' filters; empty or None fields filter nothing.

    ``query`` matches the name or the id (any case); ``season`` is a season (``"2018"``...) or
    :data:`NO_SEASON`; lengths and widths are inclusive bounds in metres."""

    query: str = ""
    season: str = ""
    direction: str = ""
    source: str = ""
    min_length_m: float | None = None
    max_length_m: float | None = None
    min_width_m: float | None = None
    max_width_m: float | None = None

    def matches(self, row: TrackRow) -> bool:
        info = row.info
        words = self.query.casefold().split()
        return (
            all(word in row.search_text for word in words)
            and (not self.season or (info.season or NO_SEASON) == self.season)
            and (not self.direction or info.direction == self.direction)
            and (not self.source or info.source == self.source)
            and (self.min_length_m is None or info.length_m >= self.min_length_m)
            and (self.max_length_m is None or info.length_m <= self.max_length_m)
            and (self.min_width_m is None or info.width_m >= self.min_width_m)
            and (self.max_width_m is None or info.width_m <= self.max_width_m)
        )


@dataclass(frozen=True, slots=True)
class TrackPreview:
    """A rendered preview: PNG bytes and their strong ETag (without quotes)."""

    png: bytes
    etag: str


_preview_cache: dict[str, TrackPreview] = {}
_preview_lock = threading.Lock()
_race_cache: OrderedDict[str, TrackPreview] = OrderedDict()
RACE_CACHE_SIZE = 64
"""Race layouts kept rendered (the last asked for): a wizard's changes ask for a few each."""


def track_rows(track_filter: TrackFilter | None = None) -> list[TrackRow]:
    """Every track, in the catalogue's order; with ``track_filter``, those it matches."""
    rows = [
        TrackRow(info=info, direction_label=DIRECTION_LABELS.get(info.direction, info.direction))
        for info in track_catalog().list()
    ]
    if track_filter is None:
        return rows
    return [row for row in rows if track_filter.matches(row)]


def track_seasons(rows: list[TrackRow]) -> list[tuple[str, str]]:
    """The season filter's choices for ``rows``: ``(value, label)``, newest first, then the
    tracks of no known season."""
    seasons = sorted({row.info.season for row in rows if row.info.season}, reverse=True)
    choices = [(season, season) for season in seasons]
    if any(not row.info.season for row in rows):
        choices.append((NO_SEASON, "Other"))
    return choices


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


def race_preview(
    track_id: str, direction: str, race_type: str, race: dict[str, Any], seed: int = 0
) -> TrackPreview:
    """The preview of ``track_id`` driven in ``direction`` with the objects of a race
    (``race``: :func:`training.services.race_settings`'s stored form) where an episode starts
    them; a random placement is the draw of ``seed``.

    Raises UnknownTrackError, and ValueError (in words) when the direction is not the track's
    to choose or the objects do not fit on it.
    """
    key = json.dumps([track_id, direction, race_type, race, seed], sort_keys=True)
    with _preview_lock:
        cached = _race_cache.get(key)
        if cached is not None:
            _race_cache.move_to_end(key)
            return cached
    track = track_catalog().load(track_id)
    try:
        track = track.in_direction(direction)
    except TrackError as exc:
        raise ValueError(str(exc)) from None
    png = render_race_preview_png(track, race_config(race_type, race), PREVIEW_WIDTH_PX, seed)
    preview = TrackPreview(png=png, etag=hashlib.sha256(png).hexdigest()[:32])
    with _preview_lock:
        _race_cache[key] = preview
        while len(_race_cache) > RACE_CACHE_SIZE:
            _race_cache.popitem(last=False)
    return preview


CONDITIONS_PREVIEW_SEED = 51
"""The seed of the Tracks page's sampled conditions: the same strip for everyone, every day."""
CONDITIONS_PREVIEW_SAMPLES = 3
"""How many sampled conditions the strip shows beside the clean world."""
CONDITIONS_CACHE_SIZE = 16
"""Tracks whose conditions strip is kept rendered (the last asked for)."""
_conditions_cache: OrderedDict[str, list[TrackPreview]] = OrderedDict()


@dataclass(frozen=True, slots=True)
class ConditionsSample:
    """One picture of the strip: the conditions drawn and a caption saying what they are."""

    conditions: Conditions
    label: str


def _conditions_label(conditions: Conditions, most: int = 3) -> str:
    """The ``most`` parameters drawn furthest from neutral (a share of their widest range),
    in words: ``"Ambient light -32 gray levels · Blur 1.2 pixels"``."""
    if conditions.is_clean:
        return "The clean world (the simulator as it is)"
    moved = []
    for family in IMAGE_FAMILIES:
        for name, info in parameters()[family].items():
            value = conditions.values[family][name]
            share = abs(value - info.neutral) / ((info.high - info.low) or 1.0)
            if share > 0.01:
                moved.append(
                    (share, f"{info.label} {value:.3g}{f' {info.unit}' if info.unit else ''}")
                )
    moved.sort(key=lambda pair: -pair[0])
    return " · ".join(text for _, text in moved[:most])


def conditions_samples() -> list[ConditionsSample]:
    """What the Tracks page's strip shows: the clean world, then
    :data:`CONDITIONS_PREVIEW_SAMPLES` draws of every family that changes the camera's picture
    at its widest ranges, from :data:`CONDITIONS_PREVIEW_SEED` (the same on every load)."""
    spec = ConditionsSpec.default(families=IMAGE_FAMILIES)
    rng = np.random.default_rng(CONDITIONS_PREVIEW_SEED)
    drawn = [Conditions.clean(), *(spec.sample(rng) for _ in range(CONDITIONS_PREVIEW_SAMPLES))]
    return [ConditionsSample(c, _conditions_label(c)) for c in drawn]


def conditions_preview(track_id: str, index: int) -> TrackPreview:
    """Picture ``index`` of ``track_id``'s strip (:func:`conditions_samples`): the car's camera
    at the start line under those conditions, rendered once per track (the last
    :data:`CONDITIONS_CACHE_SIZE` tracks kept). Raises UnknownTrackError, and IndexError for an
    index outside the strip."""
    samples = conditions_samples()
    if not 0 <= index < len(samples):
        raise IndexError(f"the strip has {len(samples)} pictures")
    with _preview_lock:
        cached = _conditions_cache.get(track_id)
        if cached is not None:
            _conditions_cache.move_to_end(track_id)
            return cached[index]
    track = track_catalog().load(track_id)
    pngs = render_conditions_preview_png(track, [sample.conditions for sample in samples])
    previews = [TrackPreview(png=png, etag=hashlib.sha256(png).hexdigest()[:32]) for png in pngs]
    with _preview_lock:
        _conditions_cache[track_id] = previews
        while len(_conditions_cache) > CONDITIONS_CACHE_SIZE:
            _conditions_cache.popitem(last=False)
    return previews[index]


def preview_cache_clear() -> None:
    """Forget every rendered preview (e.g. after a track was imported again)."""
    with _preview_lock:
        _preview_cache.clear()
        _race_cache.clear()
        _conditions_cache.clear()
