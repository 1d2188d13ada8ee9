"""DeepRacer's track catalogue, built in: the files byte-identical to their recorded hashes, the
licence and attribution beside them (and in the wheel), the console names in the catalogue,
track ids unique without regard to case, and a DeepRacer file recognised instead of imported."""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from racing.track import Track, TrackError
from racing.tracks import (
    BUILTIN_DIR,
    DEEPRACER_DIR,
    TrackCatalog,
    builtin_track_id,
    deepracer_manifest,
    deepracer_track_for,
    import_track,
    is_builtin,
)

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = json.loads((DEEPRACER_DIR / "manifest.json").read_text())
SIMAPP_MASTER = "01f5f015fd852f952b351643898d4beb4f36494b"
SIMAPP_TAG = "c74d20ae8ae5b023391d168f29ebcd3c00aa42c6"


def git_blob_id(data: bytes) -> str:
    """What ``git hash-object`` prints for a file of these bytes."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def test_every_shipped_file_is_byte_identical_to_its_recorded_hash() -> None:
    files = {p.stem: p.read_bytes() for p in DEEPRACER_DIR.glob("*.npy")}
    tracks = MANIFEST["tracks"]
    assert len(files) == 78 and set(files) == set(tracks)
    for track_id, data in files.items():
        entry = tracks[track_id]
        assert hashlib.sha256(data).hexdigest() == entry["sha256"], track_id
        assert git_blob_id(data) == entry["git_blob"], track_id  # the simapp's own blob
        assert entry["source_ref"] in ("master", "tag v5.3.3b")
    assert tracks["2022_reinvent_champ"]["source_ref"] == "tag v5.3.3b"
    assert sum(len(d) for d in files.values()) == 694_608
    assert set(MANIFEST["source"]["commits"].values()) == {SIMAPP_MASTER, SIMAPP_TAG}


def test_licence_and_attribution_sit_beside_the_files() -> None:
    licence = (DEEPRACER_DIR / "LICENSE").read_text()
    assert "Apache License" in licence and "Version 2.0, January 2004" in licence
    attribution = (DEEPRACER_DIR / "ATTRIBUTION.md").read_text()
    for needed in ("aws-deepracer-community/deepracer-simapp", SIMAPP_MASTER, SIMAPP_TAG,
                   "Apache License 2.0", "LICENSE", "not affiliated"):  # fmt: skip
        assert needed in attribution, needed


def test_the_catalogue_shows_console_names_lengths_widths_directions() -> None:
    catalog = TrackCatalog()
    listed = {info.id: info for info in catalog.list()}
    deepracer = {i: info for i, info in listed.items() if info.source == "deepracer"}
    assert set(deepracer) == set(MANIFEST["tracks"])
    base = deepracer["reinvent_base"]
    assert (base.name, base.season, base.direction) == ("re:Invent 2018", "2018", "ccw")
    assert base.length_m == pytest.approx(17.71) and base.width_m == pytest.approx(0.761)
    assert deepracer["2022_april_open"].name == "Ace Speedway"
    assert deepracer["Tokyo_Training_track"].name == "Kumo Torakku Training"
    assert deepracer["2024_reinvent_champ_cw"].name == "Forever Raceway (clockwise)"
    assert deepracer["2024_reinvent_champ_cw"].direction == "cw"
    assert (
        deepracer["Straight_track"].direction == "open" and not deepracer["Straight_track"].closed
    )
    # byte-identical scenery aliases point at the track the console names
    assert deepracer["reinvent_wood"].same_as == "reinvent_base"
    assert deepracer["Monaco_building"].same_as == "Monaco"
    assert all(info.name for info in deepracer.values())
    # what the catalogue lists without loading is what loading measures
    track = catalog.load("reinvent_base")
    assert isinstance(track, Track) and track.name == "re:Invent 2018"
    assert catalog.info("reinvent_base") == base
    assert catalog.sha256("reinvent_base") == MANIFEST["tracks"]["reinvent_base"]["sha256"]
    assert list(listed)[:3] == sorted(p.stem for p in BUILTIN_DIR.glob("*.npy"))


def test_builtin_lookups() -> None:
    assert is_builtin("reinvent_base") and is_builtin("racecraft_oval")
    assert not is_builtin("REINVENT_BASE") and not is_builtin("my_track")
    assert builtin_track_id("REINVENT_base") == "reinvent_base"
    assert builtin_track_id("Racecraft_Summit") == "racecraft_summit"
    assert builtin_track_id("nope") is None
    assert set(deepracer_manifest()) == set(MANIFEST["tracks"])


LOOK_ALIKES = ["RACECRAFT_SUMMIT", "Racecraft_Oval", "REINVENT_BASE", "reInvent2019_TRACK"]


@pytest.mark.parametrize("look_alike", LOOK_ALIKES)
def test_an_id_differing_only_in_case_from_a_builtin_is_refused(
    tmp_path: Path, look_alike: str
) -> None:
    data = (BUILTIN_DIR / "racecraft_summit.npy").read_bytes()
    with pytest.raises(TrackError, match="differs only in case from the built-in track"):
        import_track(data, track_id=look_alike, dest_dir=tmp_path, overwrite=True)
    assert list(tmp_path.iterdir()) == []


def test_the_exact_id_of_a_deepracer_track_is_refused(tmp_path: Path) -> None:
    data = (BUILTIN_DIR / "racecraft_summit.npy").read_bytes()
    with pytest.raises(TrackError, match="'reinvent_base' is the id of a built-in track"):
        import_track(data, track_id="reinvent_base", dest_dir=tmp_path, overwrite=True)


def test_an_id_differing_only_in_case_from_an_imported_track_is_refused(tmp_path: Path) -> None:
    data = (BUILTIN_DIR / "racecraft_summit.npy").read_bytes()
    import_track(data, track_id="My_Loop", dest_dir=tmp_path)
    with pytest.raises(TrackError, match="'my_loop' differs only in case from the track 'My_Loop'"):
        import_track(data, track_id="my_loop", dest_dir=tmp_path, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["My_Loop.json", "My_Loop.npy"]


def test_a_look_alike_imported_before_the_rule_stays_but_no_new_one_comes(tmp_path: Path) -> None:
    data = (BUILTIN_DIR / "racecraft_summit.npy").read_bytes()
    (tmp_path / "Loop.npy").write_bytes(data)  # two files of an earlier version, by hand
    (tmp_path / "loop.npy").write_bytes(data)
    (tmp_path / "racecraft_summit.npy").write_bytes(data)  # a built-in's own id: hidden
    catalog = TrackCatalog([tmp_path])
    assert {"Loop", "loop"} <= set(catalog.ids())  # their models keep their tracks
    assert catalog.info("racecraft_summit").source == "racecraft"
    with pytest.raises(TrackError, match="'LOOP' differs only in case from the track"):
        import_track(data, track_id="LOOP", dest_dir=tmp_path)


@pytest.mark.parametrize("track_id", ["reinvent_base", "reinvent_wood", "2022_reinvent_champ"])
def test_a_deepracer_file_is_recognised_not_imported(tmp_path: Path, track_id: str) -> None:
    data = (DEEPRACER_DIR / f"{track_id}.npy").read_bytes()
    canonical = MANIFEST["tracks"][track_id]["same_as"] or track_id
    name = MANIFEST["tracks"][canonical]["name"]
    assert deepracer_track_for(data) == canonical
    with pytest.raises(TrackError, match=f"this file is DeepRacer's '{name}' track, built in as "
                                         f"'{canonical}'"):  # fmt: skip
        import_track(data, track_id="my_copy", dest_dir=tmp_path)
    assert not tmp_path.joinpath("my_copy.npy").exists()


def test_the_cleaned_copy_of_a_deepracer_file_is_recognised_too(tmp_path: Path) -> None:
    # 2022_april_open has a consecutive duplicate row, which an import drops: what an earlier
    # import of it stored is recognised as well, also in an imported folder.
    raw = (DEEPRACER_DIR / "2022_april_open.npy").read_bytes()
    cleaned = npy(Track.from_array(np.load(io.BytesIO(raw))).to_array())
    assert cleaned != raw
    assert deepracer_track_for(cleaned) == "2022_april_open"
    (tmp_path / "ace.npy").write_bytes(cleaned)  # imported before the track was built in
    info = TrackCatalog([tmp_path]).info("ace")
    assert info.source == "imported" and info.same_as == "2022_april_open"
    assert deepracer_track_for(npy(np.load(io.BytesIO(raw)) * 1.01)) is None


@pytest.mark.slow
def test_the_wheel_and_sdist_carry_the_tracks_licence_and_attribution(tmp_path: Path) -> None:
    """Build the wheel and the sdist from the working tree (no network: no build isolation)
    and look in them."""
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
         "--no-index", "-w", str(tmp_path), str(ROOT)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-2000:]
    wheel = next(tmp_path.glob("racecraft-*.whl"))
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        for track_id, entry in MANIFEST["tracks"].items():
            member = f"racing/tracks/deepracer/{track_id}.npy"
            assert member in names, member
            assert hashlib.sha256(archive.read(member)).hexdigest() == entry["sha256"]
        for member in ("LICENSE", "ATTRIBUTION.md", "manifest.json"):
            assert f"racing/tracks/deepracer/{member}" in names, member
        assert "racing/tracks/racecraft_oval.npy" in names
    sdist_dir = tmp_path / "sdist"
    built = subprocess.run(
        [sys.executable, "-c", "import sys; from setuptools import build_meta; "
         "build_meta.build_sdist(sys.argv[1])", str(sdist_dir)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-2000:]
    with tarfile.open(next(sdist_dir.glob("racecraft-*.tar.gz"))) as sdist:
        members = {m.name.split("/", 1)[1] for m in sdist.getmembers() if "/" in m.name}
    wanted = {f"racing/tracks/deepracer/{t}.npy" for t in MANIFEST["tracks"]}
    wanted |= {
        f"racing/tracks/deepracer/{m}" for m in ("LICENSE", "ATTRIBUTION.md", "manifest.json")
    }
    assert wanted <= members, sorted(wanted - members)[:5]
