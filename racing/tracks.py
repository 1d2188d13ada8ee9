"""The track catalogue: the project's own tracks plus DeepRacer track files a user imported.

Built-in tracks live in ``racing/tracks/`` as DeepRacer-format ``.npy`` files with a
``catalog.json`` of display names. Imported tracks are ``<id>.npy`` files (with an optional
``<id>.json`` holding ``{"name": ...}``) in folders passed as ``extra_dirs``.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from racing.track import Track, TrackError, parse_waypoints

BUILTIN_DIR = Path(__file__).resolve().parent / "tracks"
TRACK_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_\-]{0,63}\Z")
MAX_TRACK_FILE_BYTES = 2_000_000
"""Largest track file accepted for import (the biggest DeepRacer file is about 30 kB)."""


class UnknownTrackError(KeyError):
    """No track has that id."""

    def __str__(self) -> str:
        return f"unknown track {self.args[0]!r}"


@dataclass(frozen=True)
class TrackInfo:
    id: str
    name: str
    length_m: float
    width_m: float
    direction: str
    closed: bool
    source: str
    description: str = ""


@lru_cache(maxsize=256)
def _file_sha256(path: str, mtime_ns: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@lru_cache(maxsize=64)
def _load_cached(path: str, mtime_ns: int, name: str) -> Track:
    return Track.from_file(path, name=name)


def _read_names(folder: Path) -> dict[str, dict]:
    catalog = folder / "catalog.json"
    if catalog.is_file():
        try:
            names = json.loads(catalog.read_text())
        except ValueError:
            return {}
        return names if isinstance(names, dict) else {}
    return {}


class TrackCatalog:
    """Every track a user can pick: built-in first, then imported ones, by id."""

    def __init__(self, extra_dirs: list[str | Path] | tuple[str | Path, ...] = ()) -> None:
        self.dirs: list[tuple[Path, str]] = [(BUILTIN_DIR, "racecraft")]
        self.dirs += [(Path(d), "imported") for d in extra_dirs]

    def _entries(self) -> dict[str, tuple[Path, str, dict]]:
        found: dict[str, tuple[Path, str, dict]] = {}
        for folder, source in self.dirs:
            if not folder.is_dir():
                continue
            names = _read_names(folder)
            for path in sorted(folder.glob("*.npy")):
                track_id = path.stem
                if track_id in found or not TRACK_ID_RE.match(track_id):
                    continue
                meta = dict(names.get(track_id, {}))
                side = path.with_suffix(".json")
                if side.is_file():
                    try:
                        meta.update(json.loads(side.read_text()))
                    except ValueError:
                        pass
                found[track_id] = (path, source, meta)
        return found

    def ids(self) -> list[str]:
        return list(self._entries())

    def load(self, track_id: str) -> Track:
        """The track with this id in its native direction; :class:`UnknownTrackError` if none."""
        entry = self._entries().get(track_id)
        if entry is None:
            raise UnknownTrackError(track_id)
        path, _, meta = entry
        return _load_cached(str(path), path.stat().st_mtime_ns, meta.get("name", track_id))

    def sha256(self, track_id: str) -> str:
        """The SHA-256 of the track's file (hex): what identifies its content on any machine."""
        entry = self._entries().get(track_id)
        if entry is None:
            raise UnknownTrackError(track_id)
        path = entry[0]
        return _file_sha256(str(path), path.stat().st_mtime_ns)

    def info(self, track_id: str) -> TrackInfo:
        entry = self._entries().get(track_id)
        if entry is None:
            raise UnknownTrackError(track_id)
        return self._info(track_id, entry)

    def _info(self, track_id: str, entry: tuple[Path, str, dict]) -> TrackInfo:
        path, source, meta = entry
        track = _load_cached(str(path), path.stat().st_mtime_ns, meta.get("name", track_id))
        return TrackInfo(
            id=track_id,
            name=track.name,
            length_m=round(track.length, 2),
            width_m=round(track.width, 3),
            direction=track.direction,
            closed=track.closed,
            source=source,
            description=meta.get("description", ""),
        )

    def list(self) -> list[TrackInfo]:
        """Every usable track; a broken imported file is skipped, never fatal."""
        infos = []
        for track_id, entry in self._entries().items():
            try:
                infos.append(self._info(track_id, entry))
            except (TrackError, OSError):
                continue
        return infos


def import_track(
    data: bytes, *, track_id: str, dest_dir: str | Path, name: str = "", overwrite: bool = False
) -> TrackInfo:
    """Validate a DeepRacer ``.npy`` track file and store it as ``<dest_dir>/<track_id>.npy``.

    Raises :class:`TrackError` with a clear message for a bad id, an oversized or unreadable
    file, or geometry that is not a track (see :meth:`Track.from_array`).
    """
    if not TRACK_ID_RE.match(track_id):
        raise TrackError(
            "a track id is 1-64 letters, digits, '_' or '-', starting with a letter or digit"
        )
    if len(data) > MAX_TRACK_FILE_BYTES:
        raise TrackError(f"track file is {len(data)} bytes; the limit is {MAX_TRACK_FILE_BYTES}")
    array = parse_waypoints(data)
    track = Track.from_array(array, track_id=track_id, name=name or track_id)
    dest = Path(dest_dir)
    if (BUILTIN_DIR / f"{track_id}.npy").exists():
        raise TrackError(f"{track_id!r} is the id of a built-in track; choose another id")
    target = dest / f"{track_id}.npy"
    if target.exists() and not overwrite:
        raise TrackError(f"a track with id {track_id!r} exists already")
    dest.mkdir(parents=True, exist_ok=True)
    np.save(target, track.to_array())
    (dest / f"{track_id}.json").write_text(json.dumps({"name": track.name}))
    return TrackCatalog([dest]).info(track_id)
