"""Tracks: importing a DeepRacer track file from the console.

The same validation as ``manage.py import_track`` (:func:`racing.tracks.import_track`: the id,
the size, the waypoints, the geometry), run in a scratch folder next to the catalogue; only a
file that passed is recorded in the database (:mod:`training.services.trackfiles`: every
machine gets it from there) and moved in, with ``os.replace``, so a bad or interrupted upload
never leaves a half-written track behind. Imported tracks are shared by every user of the
installation. Track ids are unique without regard to case, and an id (in any case) of a built-in
track is refused; a file byte-identical to one of DeepRacer's built-in tracks is recognised as
that track and not imported again.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

from django.conf import settings

from racing.preview import render_preview_png
from racing.track import TrackError
from racing.tracks import (
    MAX_TRACK_FILE_BYTES,
    TrackCatalog,
    TrackInfo,
    builtin_duplicate,
    import_track,
    track_id_refusal,
)
from training.errors import ServiceError
from training.models import TrackFile
from training.services.checks import track_catalog
from training.services.trackfiles import trackfile_save, tracks_sync


@dataclass(frozen=True)
class TrackCheck:
    """A track file that passed validation: what the catalogue would show, and its preview."""

    info: TrackInfo
    preview_png: bytes


def default_track_id(filename: str) -> str:
    """A track id from an upload's file name (``reInvent 2018.npy`` → ``reInvent_2018``)."""
    stem = Path(filename or "track").stem
    return re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_-")[:64] or "track"


def _check_free(track_id: str, local_ids: list[str], *, overwrite: bool) -> None:
    """Refuse ``track_id`` when a track has it (``overwrite`` replaces that one) or has it
    without regard to case (never replaced: ids are unique without regard to case)."""
    fold = track_id.casefold()
    others = [t for t in local_ids if t.casefold() == fold]
    others += TrackFile.objects.filter(track_id__iexact=track_id).values_list("track_id", flat=True)
    look_alikes = [t for t in others if t != track_id]
    if look_alikes:
        raise ServiceError(
            f"{track_id!r} differs only in case from the track {look_alikes[0]!r}; track ids "
            "are unique without regard to case: choose another id",
            field="track_id",
        )
    if others and not overwrite:
        raise ServiceError(f"a track with id {track_id!r} exists already", field="track_id")


def _validated(data: bytes, track_id: str, name: str, scratch: Path, *,
               overwrite: bool = False) -> TrackInfo:  # fmt: skip
    if not data:
        raise ServiceError("choose a DeepRacer .npy track file", field="file")
    if len(data) > MAX_TRACK_FILE_BYTES:
        raise ServiceError(
            f"the file is {len(data):,} bytes; a track file is at most {MAX_TRACK_FILE_BYTES:,}",
            field="file",
        )
    known = builtin_duplicate(data)  # whatever its name: the racer wants that track
    if known:
        raise ServiceError(known, field="file")
    refusal = track_id_refusal(track_id)  # a built-in's id: --overwrite cannot pass it
    if refusal:
        raise ServiceError(refusal, field="track_id")
    _check_free(track_id, track_catalog().ids(), overwrite=overwrite)
    try:
        return import_track(data, track_id=track_id, dest_dir=scratch, name=name)
    except TrackError as exc:
        field = "track_id" if "track id" in str(exc) or "built-in" in str(exc) else "file"
        raise ServiceError(str(exc), field=field) from None


def _scratch(dest: Path) -> tempfile.TemporaryDirectory:
    dest.mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(prefix=".upload-", dir=dest)  # same file system


def track_check(*, data: bytes, track_id: str, name: str = "") -> TrackCheck:
    """Validate an uploaded track file without adding it; the preview shows it as the gallery
    will. Raises :class:`ServiceError` naming the field at fault."""
    dest = Path(settings.RACECRAFT_TRACKS_DIR)
    with _scratch(dest) as scratch:
        info = _validated(data, track_id, name, Path(scratch))
        track = TrackCatalog([scratch]).load(track_id)
        return TrackCheck(info, render_preview_png(track, width_px=480))


def track_import(*, user, data: bytes, track_id: str, name: str = "") -> TrackInfo:
    """Add a validated track file to the catalogue for everyone: recorded in the database
    (every machine writes it into its own ``RACECRAFT_TRACKS_DIR`` when it needs it,
    :func:`~training.services.trackfiles.tracks_sync`), and into this machine's folder now.

    ``user`` must be signed in. All or nothing: the files are written to a scratch folder and
    moved in once they passed and were recorded (the ``.npy`` last, which is what the catalogue
    lists)."""
    if user is None or not user.is_authenticated:
        raise ServiceError("sign in to import a track")
    return track_add(data=data, track_id=track_id, name=name, user=user)


def track_add(*, data: bytes, track_id: str, name: str = "", user=None,
              overwrite: bool = False) -> TrackInfo:  # fmt: skip
    """:func:`track_import` for the command line (``manage.py import_track``), where
    ``overwrite`` replaces a track of that id everywhere."""
    dest = Path(settings.RACECRAFT_TRACKS_DIR)
    tracks_sync(dest)  # an id taken on another machine is taken here too
    with _scratch(dest) as scratch:
        _validated(data, track_id, name, Path(scratch), overwrite=overwrite)
        # raced by another upload
        _check_free(track_id, [p.stem for p in dest.glob("*.npy")], overwrite=overwrite)
        stored = (Path(scratch) / f"{track_id}.npy").read_bytes()
        row = trackfile_save(track_id=track_id, name=name or track_id, data=stored, user=user)
        (Path(scratch) / f"{track_id}.sha256").write_text(row.sha256)
        os.replace(Path(scratch) / f"{track_id}.json", dest / f"{track_id}.json")
        os.replace(Path(scratch) / f"{track_id}.npy", dest / f"{track_id}.npy")
        os.replace(Path(scratch) / f"{track_id}.sha256", dest / f"{track_id}.sha256")
    return track_catalog().info(track_id)
