"""``manage.py import_track``: DeepRacer files in (recorded for every machine), clear errors
for bad ones."""

from __future__ import annotations

from io import StringIO
from pathlib import Path

import numpy as np
import pytest
from django.core.management import CommandError, call_command

from racing.tracks import DEEPRACER_DIR, TrackCatalog
from training.models import TrackFile

pytestmark = pytest.mark.django_db  # the command records the track for every machine


@pytest.fixture
def tracks_dir(tmp_path, settings):
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    return settings.RACECRAFT_TRACKS_DIR


def _moved_reinvent(tmp_path: Path, stem: str = "my_reinvent") -> Path:
    """DeepRacer's re:Invent 2018 file moved 1 m along x: a DeepRacer file that is not built in."""
    path = tmp_path / f"{stem}.npy"
    np.save(path, np.load(DEEPRACER_DIR / "reinvent_base.npy") + np.array([1.0, 0.0] * 3))
    return path


def test_imports_a_deepracer_file(tracks_dir, tmp_path):
    source = _moved_reinvent(tmp_path)
    out = StringIO()
    call_command("import_track", str(source), "--name", "My re:Invent", stdout=out)
    assert "imported 'my_reinvent' (My re:Invent): 17.71 m long" in out.getvalue()
    info = TrackCatalog([tracks_dir]).info("my_reinvent")
    assert info.source == "imported" and info.direction == "ccw"
    recorded = TrackFile.objects.get(track_id="my_reinvent")
    assert bytes(recorded.data) == (tracks_dir / "my_reinvent.npy").read_bytes()
    with pytest.raises(CommandError, match="exists already"):
        call_command("import_track", str(source))
    with pytest.raises(CommandError, match="'MY_REINVENT' differs only in case from the track "
                                           "'my_reinvent'"):  # fmt: skip
        call_command("import_track", str(source), "--id", "MY_REINVENT", "--overwrite")
    assert list(TrackFile.objects.values_list("track_id", flat=True)) == ["my_reinvent"]


def test_a_builtin_deepracer_file_is_recognised(tracks_dir):
    source = DEEPRACER_DIR / "reinvent_base.npy"
    with pytest.raises(CommandError, match="reinvent_base.npy: this file is DeepRacer's "
                                           "'re:Invent 2018' track, built in as 'reinvent_base': "
                                           "choose it from the track list"):  # fmt: skip
        call_command("import_track", str(source), "--id", "my_copy")
    assert not TrackFile.objects.exists() and not (tracks_dir / "my_copy.npy").exists()


@pytest.mark.parametrize(
    ("track_id", "message"),
    [("RACECRAFT_SUMMIT", "'RACECRAFT_SUMMIT' differs only in case from the built-in track "
      "'racecraft_summit'"),
     ("Reinvent_Base", "differs only in case from the built-in track 'reinvent_base'"),
     ("reinvent_base", "'reinvent_base' is the id of a built-in track; choose another id")],
)  # fmt: skip
def test_an_id_shadowing_a_builtin_is_refused(tracks_dir, tmp_path, track_id, message):
    source = _moved_reinvent(tmp_path)
    with pytest.raises(CommandError, match=message):
        call_command("import_track", str(source), "--id", track_id, "--overwrite")
    assert not TrackFile.objects.exists()


def test_bad_files_are_refused_clearly(tracks_dir, tmp_path):
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((10, 5)))
    with pytest.raises(CommandError, match=r"bad.npy: .*shape \(N, 6\)"):
        call_command("import_track", str(bad))
    with pytest.raises(CommandError, match="no such file"):
        call_command("import_track", str(tmp_path / "missing.npy"))
    assert not TrackFile.objects.exists()
    assert not TrackCatalog([tracks_dir]).list() or all(
        t.source in ("racecraft", "deepracer") for t in TrackCatalog([tracks_dir]).list()
    )
