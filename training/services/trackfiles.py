"""Imported tracks by content: their files live in the database (:class:`TrackFile`), and each
machine writes them into its own ``RACECRAFT_TRACKS_DIR`` before it needs them
(:func:`tracks_sync`), so a worker that shares no disk with the web trains, evaluates and
validates on a track uploaded through the web. A local copy is kept while its ``.sha256``
sidecar matches the row (cached by content); a track imported again with ``--overwrite`` is
written anew everywhere. Built-in tracks (the project's and DeepRacer's) ship with the code
and have no row; a row left from importing a DeepRacer file before it was built in is shadowed
by the built-in track of that id.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from pathlib import Path

from django.conf import settings
from django.db import transaction

from racing.track import TrackError
from racing.tracks import TRACK_ID_RE, is_builtin
from training.errors import ServiceError
from training.models import TrackFile
from training.services.checks import track_catalog

log = logging.getLogger(__name__)


def _sidecar(folder: Path, track_id: str) -> Path:
    return folder / f"{track_id}.sha256"


def _local_sha(folder: Path, track_id: str) -> str | None:
    if not (folder / f"{track_id}.npy").is_file():
        return None
    try:
        return _sidecar(folder, track_id).read_text().strip()
    except OSError:
        return None


def trackfile_save(*, track_id: str, name: str, data: bytes, user=None) -> TrackFile:
    """Record a validated track file (the ``.npy`` as the catalogue stores it); a track id
    recorded already is replaced (``import_track --overwrite``)."""
    with transaction.atomic():
        row, _ = TrackFile.objects.update_or_create(
            track_id=track_id,
            defaults={"name": name[:200], "data": data, "created_by": user,
                      "sha256": hashlib.sha256(data).hexdigest()},
        )  # fmt: skip
    return row


def track_recorded(track_id: str) -> bool:
    """Whether ``track_id`` is a track every machine can have: built in, or recorded."""
    if is_builtin(track_id):
        return True
    return TrackFile.objects.filter(track_id=track_id).exists()


def tracks_sync(folder: str | Path | None = None) -> list[str]:
    """Write every recorded track that this machine's ``folder`` (``RACECRAFT_TRACKS_DIR``)
    lacks, or holds in another version, from the database; returns the ids written. Each file
    goes in whole (written aside, then renamed; the sidecar last), so a reader sees the old
    version or the new one, never half a file."""
    dest = Path(folder or settings.RACECRAFT_TRACKS_DIR)
    written = []
    for track_id, sha, name in TrackFile.objects.values_list("track_id", "sha256", "name"):
        if not TRACK_ID_RE.match(track_id) or _local_sha(dest, track_id) == sha:
            continue
        data = bytes(TrackFile.objects.values_list("data", flat=True).get(track_id=track_id))
        if hashlib.sha256(data).hexdigest() != sha:
            log.error("track %s: the recorded file does not match its hash; not written", track_id)
            continue
        dest.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=".sync-", dir=dest) as scratch:
            aside = Path(scratch)
            (aside / "name.json").write_text(json.dumps({"name": name or track_id}))
            (aside / "track.npy").write_bytes(data)
            (aside / "sha256").write_text(sha)
            os.replace(aside / "name.json", dest / f"{track_id}.json")
            os.replace(aside / "track.npy", dest / f"{track_id}.npy")
            os.replace(aside / "sha256", _sidecar(dest, track_id))
        written.append(track_id)
    return written


def tracks_sync_for(track_ids: list[str]) -> list[str]:
    """:func:`tracks_sync` when any of ``track_ids`` is an imported track; built-in tracks ship
    with the code, so a job on them asks the database nothing."""
    if all(is_builtin(t) for t in track_ids):
        return []
    return tracks_sync()


def track_hashes(track_ids: list[str]) -> tuple[tuple[str, str], ...]:
    """``(track id, SHA-256)`` of those of ``track_ids`` that are recorded (imported): what a
    job's env spec carries so that every machine checks it drives the same content. A row
    left from an import made before the track was built in is no longer the track: the
    built-in file is what every machine drives."""
    rows = dict(TrackFile.objects.filter(track_id__in=set(track_ids))
                .values_list("track_id", "sha256"))  # fmt: skip
    return tuple((t, rows[t]) for t in dict.fromkeys(track_ids) if t in rows and not is_builtin(t))


def tracks_check_recorded(track_ids: list[str]) -> None:
    """Refuse a job on a track no machine can have (gone from the catalogue since). A file put
    into this machine's folder by hand, never recorded, is recorded now (read and checked as
    the catalogue reads it), so that a worker that shares no disk with this one gets it too."""
    catalog = None
    for track_id in track_ids:
        if track_recorded(track_id):
            continue
        if catalog is None:
            catalog = track_catalog()
        if track_id not in catalog.ids():
            raise ServiceError(
                f"the track {track_id!r} is no longer in the catalogue: import it again, or "
                "clone the model onto another track"
            )
        folder = Path(settings.RACECRAFT_TRACKS_DIR)
        try:
            catalog.load(track_id)  # the file is a track the simulator can drive
            data = (folder / f"{track_id}.npy").read_bytes()
        except (OSError, TrackError) as exc:
            raise ServiceError(f"the track {track_id!r} cannot be read here: {exc}") from None
        trackfile_save(track_id=track_id, name=catalog.info(track_id).name, data=data)
        _sidecar(folder, track_id).write_text(hashlib.sha256(data).hexdigest())
        log.info("track %s: a file put here by hand is now recorded for every machine", track_id)
