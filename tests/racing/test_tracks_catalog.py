"""TrackCatalog and import_track: built-in tracks, importing DeepRacer files, bad ids."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from racing.track import Track, TrackError
from racing.tracks import (
    BUILTIN_DIR,
    DEEPRACER_DIR,
    TrackCatalog,
    UnknownTrackError,
    import_track,
)

OVAL_TRACK = DEEPRACER_DIR / "Oval_track.npy"

BUILTIN = {
    # id: (name, length range m, width m)
    "racecraft_summit": ("Racecraft Summit Loop", (17.0, 18.0), 0.76),
    "racecraft_oval": ("Racecraft Oval", (20.0, 22.0), 1.5),
    "racecraft_technical": ("Racecraft Technical Circuit", (30.0, 37.0), 1.067),
}


def builtin_bytes(track_id: str = "racecraft_oval") -> bytes:
    return (BUILTIN_DIR / f"{track_id}.npy").read_bytes()


def test_catalog_lists_the_builtin_tracks() -> None:
    infos = {info.id: info for info in TrackCatalog().list()}
    assert set(BUILTIN) <= set(infos)
    for track_id, (name, (low, high), width) in BUILTIN.items():
        info = infos[track_id]
        assert info.name == name
        assert low <= info.length_m <= high
        assert info.width_m == pytest.approx(width, abs=0.005)
        assert info.direction == "ccw"
        assert info.closed
        assert info.source == "racecraft"
        assert info.description.endswith(".")


def test_catalog_json_and_files_agree() -> None:
    names = json.loads((BUILTIN_DIR / "catalog.json").read_text())
    files = {p.stem for p in BUILTIN_DIR.glob("*.npy")}
    assert set(names) == files == set(BUILTIN)  # DeepRacer's live in deepracer/
    for entry in names.values():
        assert set(entry) == {"name", "description"}
        assert entry["name"] and entry["description"]


def test_load_builtin_track() -> None:
    track = TrackCatalog().load("racecraft_summit")
    assert isinstance(track, Track)
    assert track.name == "Racecraft Summit Loop"
    assert track.track_id == "racecraft_summit"


def test_load_unknown_id_raises() -> None:
    catalog = TrackCatalog()
    with pytest.raises(UnknownTrackError, match="unknown track 'no_such_track'"):
        catalog.load("no_such_track")
    with pytest.raises(KeyError):  # UnknownTrackError is a KeyError
        catalog.info("no_such_track")
    assert str(UnknownTrackError("x")) == "unknown track 'x'"


def test_import_a_deepracer_file(tmp_path: Path) -> None:
    # DeepRacer's Oval Track moved 1 m along x: a DeepRacer-format file that is not built in.
    moved = np.load(OVAL_TRACK) + np.array([1.0, 0.0] * 3)
    path = tmp_path / "moved.npy"
    np.save(path, moved)
    lib = tmp_path / "lib"
    info = import_track(path.read_bytes(), track_id="my_oval", dest_dir=lib, name="My Oval")
    assert info.source == "imported" and not info.same_as
    assert info.name == "My Oval"
    assert info.length_m == pytest.approx(19.55, abs=0.01)
    assert info.width_m == pytest.approx(0.609, abs=0.005)
    assert info.direction == "ccw"
    catalog = TrackCatalog([lib])
    assert "my_oval" in catalog.ids()
    listed = {i.id: i for i in catalog.list()}
    assert listed["my_oval"].source == "imported"
    assert listed["racecraft_oval"].source == "racecraft"
    assert listed["Oval_track"].source == "deepracer"
    assert catalog.load("my_oval").length == pytest.approx(19.55, abs=0.01)
    assert sorted(p.name for p in lib.iterdir()) == ["my_oval.json", "my_oval.npy"]


def test_import_stores_a_clean_copy(tmp_path: Path) -> None:
    array = np.load(BUILTIN_DIR / "racecraft_summit.npy")
    doubled = np.insert(array, 10, array[10], axis=0)  # a consecutive duplicate row
    path = tmp_path / "in.npy"
    np.save(path, doubled)
    info = import_track(path.read_bytes(), track_id="summit-copy", dest_dir=tmp_path / "lib")
    assert info.id == "summit-copy" and info.name == "summit-copy"
    assert np.array_equal(np.load(tmp_path / "lib" / "summit-copy.npy"), array)


@pytest.mark.parametrize(
    "bad_id",
    ["../x", "..", "", "a" * 65, "x/y", "x\\y", ".hidden", "_x", "-x", "abc\n", "a b", "é"],
)
def test_bad_ids_are_refused(tmp_path: Path, bad_id: str) -> None:
    dest = tmp_path / "lib"
    with pytest.raises(TrackError, match="a track id is 1-64 letters"):
        import_track(builtin_bytes(), track_id=bad_id, dest_dir=dest)
    assert not dest.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_longest_id_is_accepted(tmp_path: Path) -> None:
    info = import_track(builtin_bytes(), track_id="a" * 64, dest_dir=tmp_path)
    assert info.id == "a" * 64


def test_overwrite_needs_permission(tmp_path: Path) -> None:
    import_track(builtin_bytes("racecraft_oval"), track_id="mine", dest_dir=tmp_path, name="One")
    with pytest.raises(TrackError, match="a track with id 'mine' exists already"):
        import_track(builtin_bytes("racecraft_summit"), track_id="mine", dest_dir=tmp_path)
    assert TrackCatalog([tmp_path]).info("mine").name == "One"
    info = import_track(
        builtin_bytes("racecraft_summit"),
        track_id="mine",
        dest_dir=tmp_path,
        name="Two",
        overwrite=True,
    )
    assert info.name == "Two"
    assert info.length_m == pytest.approx(TrackCatalog().info("racecraft_summit").length_m)


@pytest.mark.parametrize("track_id", list(BUILTIN))
def test_builtin_ids_are_refused(tmp_path: Path, track_id: str) -> None:
    with pytest.raises(TrackError, match="is the id of a built-in track"):
        import_track(builtin_bytes(), track_id=track_id, dest_dir=tmp_path, overwrite=True)
    assert list(tmp_path.iterdir()) == []


def test_imported_file_cannot_shadow_a_builtin(tmp_path: Path) -> None:
    (tmp_path / "racecraft_oval.npy").write_bytes(builtin_bytes("racecraft_summit"))
    catalog = TrackCatalog([tmp_path])
    assert catalog.info("racecraft_oval").source == "racecraft"
    assert catalog.info("racecraft_oval").name == "Racecraft Oval"


def test_broken_imported_file_is_skipped(tmp_path: Path) -> None:
    (tmp_path / "broken.npy").write_bytes(b"not a track")
    np.save(tmp_path / "tiny.npy", np.zeros((2, 6)))
    catalog = TrackCatalog([tmp_path])
    ids = {info.id for info in catalog.list()}
    assert "broken" not in ids and "tiny" not in ids
    assert set(BUILTIN) <= ids and "reinvent_base" in ids
    with pytest.raises(TrackError):
        catalog.load("broken")


def test_missing_import_folder_is_fine(tmp_path: Path) -> None:
    catalog = TrackCatalog([tmp_path / "nowhere"])
    assert set(catalog.ids()) == set(BUILTIN) | {p.stem for p in DEEPRACER_DIR.glob("*.npy")}
