"""``manage.py import_track``: DeepRacer files in (recorded for every machine), clear errors
for bad ones."""

from __future__ import annotations

from io import StringIO
from pathlib import Path

import numpy as np
import pytest
from django.core.management import CommandError, call_command

from racing.tracks import TrackCatalog
from training.models import TrackFile

pytestmark = pytest.mark.django_db  # the command records the track for every machine
SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "tracks"


@pytest.fixture
def tracks_dir(tmp_path, settings):
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    return settings.RACECRAFT_TRACKS_DIR


def test_imports_a_deepracer_file(tracks_dir):
    source = SHARED / "reinvent_base.npy"
    if not source.exists():
        pytest.skip("DeepRacer track files are not present")
    out = StringIO()
    call_command("import_track", str(source), "--name", "re:Invent 2018", stdout=out)
    assert "imported 'reinvent_base' (re:Invent 2018): 17.71 m long" in out.getvalue()
    info = TrackCatalog([tracks_dir]).info("reinvent_base")
    assert info.source == "imported" and info.direction == "ccw"
    recorded = TrackFile.objects.get(track_id="reinvent_base")
    assert bytes(recorded.data) == (tracks_dir / "reinvent_base.npy").read_bytes()
    with pytest.raises(CommandError, match="exists already"):
        call_command("import_track", str(source))


def test_bad_files_are_refused_clearly(tracks_dir, tmp_path):
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((10, 5)))
    with pytest.raises(CommandError, match=r"bad.npy: .*shape \(N, 6\)"):
        call_command("import_track", str(bad))
    with pytest.raises(CommandError, match="no such file"):
        call_command("import_track", str(tmp_path / "missing.npy"))
    assert not TrackFile.objects.exists()
    assert not TrackCatalog([tracks_dir]).list() or all(
        t.source == "racecraft" for t in TrackCatalog([tracks_dir]).list()
    )
