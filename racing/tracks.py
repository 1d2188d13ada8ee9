"""The track catalogue: the project's own tracks, DeepRacer's tracks, and files a user imported.

Built-in tracks ship with the package:

- ``racing/tracks/``: the project's own tracks, DeepRacer-format ``.npy`` files with a
  ``catalog.json`` of display names (source ``"racecraft"``);
- ``racing/tracks/deepracer/``: DeepRacer's track catalogue, the simulator's waypoint files
  copied byte-identical from ``aws-deepracer-community/deepracer-simapp`` (Apache-2.0, see the
  ``LICENSE`` and ``ATTRIBUTION.md`` there), each under its file stem as id, the id DeepRacer's
  ``WORLD_NAME`` and track ARNs use (source ``"deepracer"``). Their ``manifest.json`` holds the
  console name, the season, the length, width and direction our simulator measures on the file
  (checked by the tests, so listing 80 tracks loads none of them) and each file's SHA-256.

Imported tracks are ``<id>.npy`` files (with an optional ``<id>.json`` holding
``{"name": ...}``) in folders passed as ``extra_dirs``.

Track ids are unique without regard to case: an import as ``RACECRAFT_SUMMIT`` beside
``racecraft_summit`` (a look-alike) is refused.
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
DEEPRACER_DIR = BUILTIN_DIR / "deepracer"
DEEPRACER_MANIFEST = DEEPRACER_DIR / "manifest.json"
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
    season: str = ""
    """The DeepRacer league season of a DeepRacer track (``"2018"``...), ``""`` when unknown."""
    same_as: str = ""
    """The built-in track this one's file is byte-identical to (an alias such as
    ``reinvent_wood``, or an imported copy), ``""`` for none."""


@lru_cache(maxsize=1)
def deepracer_manifest() -> dict[str, dict]:
    """DeepRacer's tracks by id, from ``racing/tracks/deepracer/manifest.json`` (in file order)."""
    return json.loads(DEEPRACER_MANIFEST.read_text())["tracks"]


def builtin_track_ids() -> list[str]:
    """Every built-in track id: the project's own, then DeepRacer's."""
    own = sorted(p.stem for p in BUILTIN_DIR.glob("*.npy"))
    return own + list(deepracer_manifest())


@lru_cache(maxsize=1)
def _builtin_by_fold() -> dict[str, str]:
    return {track_id.casefold(): track_id for track_id in builtin_track_ids()}


def builtin_track_id(track_id: str) -> str | None:
    """The built-in track whose id is ``track_id`` without regard to case, else None."""
    return _builtin_by_fold().get(track_id.casefold())


def is_builtin(track_id: str) -> bool:
    """Whether ``track_id`` (exactly) is a built-in track: it ships with the code."""
    return builtin_track_id(track_id) == track_id


@lru_cache(maxsize=1)
def _deepracer_by_content() -> dict[str, str]:
    found: dict[str, str] = {}
    for track_id, meta in deepracer_manifest().items():
        canonical = meta.get("same_as") or track_id
        found.setdefault(meta["sha256"], canonical)
        found.setdefault(meta["stored_sha256"], canonical)
    return found


def deepracer_track_for(data: bytes) -> str | None:
    """The id of the DeepRacer track whose file is ``data`` byte for byte (the simapp's file, or
    the cleaned copy :func:`import_track` would store), else None. Of byte-identical aliases,
    the one the console names (``reinvent_base`` for ``reinvent_wood``'s bytes)."""
    return _deepracer_by_content().get(hashlib.sha256(data).hexdigest())


@lru_cache(maxsize=256)
def _file_sha256(path: str, mtime_ns: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@lru_cache(maxsize=128)
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
    """Every track a user can pick: built-in first (the project's, then DeepRacer's), then
    imported ones, by id (a built-in id hides an imported file of that id). Ids are kept
    unique without regard to case when a track is imported (:func:`track_id_refusal`); a
    look-alike imported before that rule stays listed, so that its models keep their track."""

    def __init__(self, extra_dirs: list[str | Path] | tuple[str | Path, ...] = ()) -> None:
        self.dirs: list[tuple[Path, str]] = [(BUILTIN_DIR, "racecraft")]
        self.dirs += [(Path(d), "imported") for d in extra_dirs]

    def _entries(self) -> dict[str, tuple[Path, str, dict]]:
        found: dict[str, tuple[Path, str, dict]] = {}

        def add(track_id: str, entry: tuple[Path, str, dict]) -> None:
            if track_id not in found and TRACK_ID_RE.match(track_id):
                found[track_id] = entry

        for folder, source in self.dirs:
            if not folder.is_dir():
                continue
            names = _read_names(folder)
            for path in sorted(folder.glob("*.npy")):
                track_id = path.stem
                meta = dict(names.get(track_id, {}))
                side = path.with_suffix(".json")
                if side.is_file():
                    try:
                        meta.update(json.loads(side.read_text()))
                    except ValueError:
                        pass
                add(track_id, (path, source, meta))
            if source == "racecraft":  # DeepRacer's catalogue right after the project's own
                for track_id, meta in deepracer_manifest().items():
                    add(track_id, (DEEPRACER_DIR / f"{track_id}.npy", "deepracer", meta))
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
        if source == "deepracer":  # measured once, recorded in the manifest (and tested)
            return TrackInfo(
                id=track_id,
                name=meta["name"],
                length_m=meta["length_m"],
                width_m=meta["width_m"],
                direction=meta["direction"],
                closed=meta["closed"],
                source=source,
                season=meta.get("season", ""),
                same_as=meta.get("same_as", ""),
            )
        track = _load_cached(str(path), path.stat().st_mtime_ns, meta.get("name", track_id))
        same_as = ""
        if source == "imported":
            sha = _file_sha256(str(path), path.stat().st_mtime_ns)
            same_as = _deepracer_by_content().get(sha, "")
        return TrackInfo(
            id=track_id,
            name=track.name,
            length_m=round(track.length, 2),
            width_m=round(track.width, 3),
            direction=track.direction,
            closed=track.closed,
            source=source,
            description=meta.get("description", ""),
            same_as=same_as,
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


def track_id_refusal(track_id: str) -> str | None:
    """Why ``track_id`` cannot name a new imported track, in words, or None when it can: the
    id's form, or a built-in track with that id without regard to case (a look-alike)."""
    if not TRACK_ID_RE.match(track_id):
        return "a track id is 1-64 letters, digits, '_' or '-', starting with a letter or digit"
    builtin = builtin_track_id(track_id)
    if builtin == track_id:
        return f"{track_id!r} is the id of a built-in track; choose another id"
    if builtin is not None:
        return (
            f"{track_id!r} differs only in case from the built-in track {builtin!r}; track ids "
            "are unique without regard to case: choose another id"
        )
    return None


def builtin_duplicate(data: bytes) -> str | None:
    """When ``data`` is one of DeepRacer's built-in track files byte for byte, a sentence that
    says which (an import would only copy it), else None."""
    known = deepracer_track_for(data)
    if known is None:
        return None
    name = deepracer_manifest()[known]["name"]
    return (
        f"this file is DeepRacer's {name!r} track, built in as {known!r}: choose it from the "
        "track list, no import needed"
    )


def import_track(
    data: bytes, *, track_id: str, dest_dir: str | Path, name: str = "", overwrite: bool = False
) -> TrackInfo:
    """Validate a DeepRacer ``.npy`` track file and store it as ``<dest_dir>/<track_id>.npy``.

    Raises :class:`TrackError` with a clear message for a bad id, an id a built-in track has
    (without regard to case) or that differs only in case from a track in ``dest_dir``, a file
    byte-identical to one of DeepRacer's built-in tracks (pick that one instead), an oversized
    or unreadable file, or geometry that is not a track (see :meth:`Track.from_array`).
    """
    refusal = track_id_refusal(track_id)
    if refusal:
        raise TrackError(refusal)
    if len(data) > MAX_TRACK_FILE_BYTES:
        raise TrackError(f"track file is {len(data)} bytes; the limit is {MAX_TRACK_FILE_BYTES}")
    known = builtin_duplicate(data)
    if known:
        raise TrackError(known)
    array = parse_waypoints(data)
    track = Track.from_array(array, track_id=track_id, name=name or track_id)
    dest = Path(dest_dir)
    target = dest / f"{track_id}.npy"
    if dest.is_dir():
        for other in dest.glob("*.npy"):
            if other.stem != track_id and other.stem.casefold() == track_id.casefold():
                raise TrackError(
                    f"{track_id!r} differs only in case from the track {other.stem!r}; track "
                    "ids are unique without regard to case: choose another id"
                )
    if target.exists() and not overwrite:
        raise TrackError(f"a track with id {track_id!r} exists already")
    dest.mkdir(parents=True, exist_ok=True)
    np.save(target, track.to_array())
    (dest / f"{track_id}.json").write_text(json.dumps({"name": track.name}))
    return TrackCatalog([dest]).info(track_id)
