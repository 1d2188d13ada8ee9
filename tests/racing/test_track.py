"""Track: loading DeepRacer files, refusing bad input, and the geometry the simulator relies on.

The DeepRacer track files are the built-in ones (racing/tracks/deepracer/), checked against
their manifest: the waypoint counts come from the independent index made when they were
copied, the lengths, widths and directions are what the catalogue lists without loading.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from racing.track import MIN_DISTINCT_POINTS, Track, TrackError
from racing.tracks import (
    BUILTIN_DIR,
    DEEPRACER_DIR,
    MAX_TRACK_FILE_BYTES,
    deepracer_manifest,
    import_track,
)

SHARED_FILES = sorted(DEEPRACER_DIR.glob("*.npy"))
BUILTIN_IDS = ["racecraft_summit", "racecraft_oval", "racecraft_technical"]


def shared_params() -> list:
    return [pytest.param(p, id=p.stem) for p in SHARED_FILES]


@pytest.fixture(scope="module")
def index() -> dict[str, dict]:
    """The manifest's entries by file name."""
    return {f"{k}.npy": v for k, v in deepracer_manifest().items()}


def ring(n: int = 48, radius: float = 2.0, width: float = 0.6) -> np.ndarray:
    """A closed circular track, counter-clockwise, as a DeepRacer (n+1, 6) array."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    unit = np.stack([np.cos(a), np.sin(a)], axis=1)
    rows = np.hstack([unit * radius, unit * (radius - width / 2), unit * (radius + width / 2)])
    return np.vstack([rows, rows[:1]])


def npy(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=allow_pickle)
    return buffer.getvalue()


# ------------------------------------------------------------------ (a) the DeepRacer files
def test_index_lists_every_shared_file(index: dict[str, dict]) -> None:
    assert len(SHARED_FILES) == 78
    assert sorted(index) == sorted(p.name for p in SHARED_FILES)


@pytest.mark.parametrize("path", shared_params())
def test_shared_file_matches_index(path: Path, index: dict[str, dict]) -> None:
    row = index[path.name]
    track = Track.from_file(path)
    assert track.length == pytest.approx(row["length_m"], abs=0.005)
    assert track.width == pytest.approx(row["width_m"], abs=0.0005)
    assert track.direction == row["direction"]
    assert track.closed == row["closed"]
    assert track.num_waypoints == row["waypoints"]  # closing row, consecutive duplicates dropped
    assert track.track_id == path.stem


@pytest.mark.parametrize("path", shared_params())
def test_shared_file_reversed(path: Path) -> None:
    track = Track.from_file(path)
    if not track.closed:
        with pytest.raises(TrackError, match="open route"):
            track.reversed()
        return
    back = track.reversed()
    assert back.length == pytest.approx(track.length, abs=1e-9)
    assert np.array_equal(back.centre[0], track.centre[0])
    assert back.direction == {"ccw": "cw", "cw": "ccw"}[track.direction]
    assert back.native_direction == track.direction
    assert back.reversed().direction == track.direction
    assert back.width == pytest.approx(track.width, abs=1e-9)
    assert track.in_direction("cw").direction == "cw"
    assert track.in_direction("ccw").direction == "ccw"
    assert back.in_direction("native").direction == track.direction
    assert np.array_equal(back.to_array(), track.to_array())


# ------------------------------------------------------------------ (b) bad input
def figure_eight(n: int = 80, width: float = 0.4) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    centre = np.stack([3 * np.sin(t), 3 * np.sin(t) * np.cos(t)], axis=1)
    d = np.gradient(np.vstack([centre[-1:], centre, centre[:1]]), axis=0)[1:-1]
    left = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    rows = np.hstack([centre, centre + left * width / 2, centre - left * width / 2])
    return np.vstack([rows, rows[:1]])


def crossed_borders() -> np.ndarray:
    rows = ring()
    rows[10:14, 2:4], rows[10:14, 4:6] = rows[10:14, 4:6].copy(), rows[10:14, 2:4].copy()
    return rows


def with_value(value: float) -> np.ndarray:
    rows = ring()
    rows[7, 3] = value
    return rows


BAD_ARRAYS = {
    "shape (N, 5)": (ring()[:, :5], r"shape \(N, 6\).*got shape \(49, 5\)"),
    "1-D": (ring()[:, 0], r"shape \(N, 6\).*got shape \(49,\)"),
    "3-D": (ring()[None], r"shape \(N, 6\)"),
    "NaN": (with_value(np.nan), r"row 7 holds NaN or infinity"),
    "inf": (with_value(np.inf), r"row 7 holds NaN or infinity"),
    "too few points": (ring(n=3), rf"at least {MIN_DISTINCT_POINTS} distinct waypoints; got 3"),
    "one row": (ring()[:1], r"at least 4 distinct waypoints; got 1"),
    "empty": (np.zeros((0, 6)), r"at least 4 distinct waypoints; got 0"),
    "figure eight": (figure_eight(), r"crosses itself"),
    "borders cross": (crossed_borders(), r"inner and outer borders cross each other"),
    "strings": (ring().astype(str), r"real numbers, not <U"),
    "object dtype": (ring().astype(object), r"real numbers, not object"),
    "complex": (ring().astype(complex), r"real numbers, not complex"),
    "bool": (np.ones((10, 6), dtype=bool), r"real numbers, not bool"),
    "not metres": (ring(radius=5000.0), r"beyond ±1000 m"),
    "too narrow": (ring(width=0.05), r"0.05 m wide; at least 0.2 m"),
}


@pytest.mark.parametrize("case", list(BAD_ARRAYS))
def test_bad_array_raises_clear_track_error(case: str) -> None:
    array, message = BAD_ARRAYS[case]
    with pytest.raises(TrackError, match=message):
        Track.from_array(array)


def test_swapped_border_columns_are_accepted_inner_is_the_smaller_loop() -> None:
    """Columns 2:4 and 4:6 swapped: DeepRacer's meaning of inner (nearer the middle) wins."""
    track = Track.from_array(ring()[:, [0, 1, 4, 5, 2, 3]])
    assert np.allclose(track.inner, ring()[:-1, 2:4])


def test_inner_border_outside_outer_border_raises() -> None:
    """Borders that do not cross but sit apart (one loop beside the other) are refused."""
    rows = ring()
    rows[:, 2:4] += [10.0, 0.0]  # "inner" loop moved well away from the outer one
    with pytest.raises(TrackError, match="inner border does not lie inside the outer border"):
        Track.from_array(rows)


def test_not_a_numpy_array_raises() -> None:
    with pytest.raises(TrackError, match=r"shape \(N, 6\)"):
        Track.from_array([[1, 2, 3]])


def test_import_rejects_a_byte_blob(tmp_path: Path) -> None:
    with pytest.raises(TrackError, match="not a NumPy .npy array"):
        import_track(b"PK\x03\x04 this is a zip, not a track", track_id="blob", dest_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_import_rejects_an_empty_file(tmp_path: Path) -> None:
    with pytest.raises(TrackError, match="not a NumPy .npy array"):
        import_track(b"", track_id="blob", dest_dir=tmp_path)


def test_import_rejects_pickled_objects(tmp_path: Path) -> None:
    data = npy(np.array([{"x": 1}] * 6, dtype=object).reshape(1, 6), allow_pickle=True)
    with pytest.raises(TrackError, match="not a NumPy .npy array"):
        import_track(data, track_id="pickle", dest_dir=tmp_path)


def test_import_rejects_string_arrays(tmp_path: Path) -> None:
    with pytest.raises(TrackError, match="real numbers"):
        import_track(npy(ring().astype(str)), track_id="strings", dest_dir=tmp_path)


def test_import_rejects_an_oversized_file(tmp_path: Path) -> None:
    data = npy(ring()) + b"\0" * MAX_TRACK_FILE_BYTES
    with pytest.raises(TrackError, match=f"the limit is {MAX_TRACK_FILE_BYTES}"):
        import_track(data, track_id="huge", dest_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_import_rejects_a_header_claiming_a_huge_array(tmp_path: Path) -> None:
    """A 200-byte file whose header claims terabytes must not escape as MemoryError."""
    header = np.lib.format.header_data_from_array_1_0(np.zeros((10, 6)))
    header["shape"] = (10**12, 6)
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, header)
    forged = buffer.getvalue() + np.zeros((10, 6)).tobytes()
    with pytest.raises(TrackError, match="not a NumPy .npy array"):
        import_track(forged, track_id="forged", dest_dir=tmp_path)


def test_from_file_rejects_a_text_file(tmp_path: Path) -> None:
    path = tmp_path / "notes.npy"
    path.write_text("centre, inner, outer\n")
    with pytest.raises(TrackError, match="notes.npy: not a NumPy .npy array"):
        Track.from_file(path)


def test_direction_must_be_known() -> None:
    with pytest.raises(TrackError, match="direction must be 'ccw', 'cw' or 'native'"):
        Track.from_array(ring()).in_direction("sideways")


def test_open_route_has_one_direction() -> None:
    rows = ring()[:20]  # first row != last row: an open arc
    track = Track.from_array(rows)
    assert track.direction == "open" and not track.closed
    with pytest.raises(TrackError, match="open route"):
        track.reversed()
    with pytest.raises(TrackError, match="open route"):
        track.in_direction("cw")


# ------------------------------------------------------------------ (c) geometry
def geometry_params() -> list:
    params = [pytest.param(BUILTIN_DIR / f"{i}.npy", id=i) for i in BUILTIN_IDS]
    params.append(pytest.param(DEEPRACER_DIR / "reinvent_base.npy", id="reinvent_base"))
    return params


@pytest.fixture(params=geometry_params())
def track(request: pytest.FixtureRequest) -> Track:
    return Track.from_file(request.param)


def mid_segment_distances(track: Track, count: int = 40) -> np.ndarray:
    """Distances along the line to the middle of ``count`` segments spread around the track."""
    segs = np.linspace(0, track.num_segments - 1, count).astype(int)
    return track.cumulative[segs] + 0.5 * (track.cumulative[segs + 1] - track.cumulative[segs])


def test_locate_centre_points(track: Track) -> None:
    for direction in (track, track.reversed()):
        for i in range(direction.num_waypoints):
            loc = direction.locate(*direction.centre[i])
            assert loc.distance == pytest.approx(0.0, abs=1e-9)
            s = direction.cumulative[i]
            assert min(abs(loc.s - s), direction.length - abs(loc.s - s)) < 1e-9


def test_offset_left_is_left_and_right_in_the_other_direction(track: Track) -> None:
    back = track.reversed()
    for s in mid_segment_distances(track):
        x, y = track.point_at(s, offset=0.2)
        loc = track.locate(x, y)
        assert loc.left is True
        assert 0.18 <= loc.distance <= 0.2 + 1e-9
        assert back.locate(x, y).left is False
        xr, yr = track.point_at(s, offset=-0.2)
        assert track.locate(xr, yr).left is False
        assert back.locate(xr, yr).left is True


def test_locate_with_hint_agrees_with_full_search(track: Track) -> None:
    for s in mid_segment_distances(track):
        x, y = track.point_at(s, offset=0.1)
        full = track.locate(x, y)
        hinted = track.locate(x, y, hint=full.segment)
        assert hinted == full


def test_point_at_round_trips_with_locate(track: Track) -> None:
    for s in np.linspace(0.0, track.length, 97, endpoint=False):
        loc = track.locate(*track.point_at(s))
        assert loc.distance == pytest.approx(0.0, abs=1e-9)
        assert min(abs(loc.s - s), track.length - abs(loc.s - s)) < 1e-6
    assert track.point_at(track.length + 1.0) == pytest.approx(track.point_at(1.0))


def test_on_track(track: Track) -> None:
    assert track.on_track(track.centre[:, 0], track.centre[:, 1]).all()
    # Just inside the borders (the car is on the road up to the painted edge).
    for s in mid_segment_distances(track):
        for offset in (0.4 * track.width, -0.4 * track.width):
            x, y = track.point_at(s, offset)
            assert track.on_track(np.array([x]), np.array([y]))[0], (s, offset)
    # 1 m beyond the outer border, away from the centre line.
    out = track.outer - track.centre
    out /= np.hypot(out[:, 0], out[:, 1])[:, None]
    far = track.outer + out
    # In a concave stretch the point could land on another part of the loop: judge those by
    # an independent polygon test first.
    loop = Polygon(track.outer)
    clear = np.array([not loop.intersects(Point(p)) for p in far])
    assert clear.mean() > 0.5
    assert not track.on_track(far[clear, 0], far[clear, 1]).any()
    # The infield is not road either.
    cx, cy = Polygon(track.inner).representative_point().coords[0]
    assert not track.on_track(np.array([cx]), np.array([cy]))[0]


def test_widths_and_length_are_consistent(track: Track) -> None:
    seg = np.hypot(*np.diff(np.vstack([track.centre, track.centre[:1]]), axis=0).T)
    assert track.length == pytest.approx(seg.sum(), rel=1e-12)
    assert track.widths.shape == (track.num_waypoints,)
    assert track.width == pytest.approx(track.widths.mean())
    xmin, ymin, xmax, ymax = track.bounds()
    assert xmin < track.centre[:, 0].min() and xmax > track.centre[:, 0].max()
    assert ymin < track.centre[:, 1].min() and ymax > track.centre[:, 1].max()


def test_heading_at_start_points_along_the_first_segment(track: Track) -> None:
    dx, dy = track.centre[1] - track.centre[0]
    assert track.heading_at(0.0) == pytest.approx(math.atan2(dy, dx))


# ------------------------------------------------------------------ (d) duplicates
def test_consecutive_duplicate_rows_are_dropped() -> None:
    rows = ring()
    clean = Track.from_array(rows)
    doubled = np.insert(rows, 5, rows[5], axis=0)  # a repeated point in the middle
    doubled = np.insert(doubled, 20, doubled[20], axis=0)
    doubled = np.insert(doubled, 20, doubled[20], axis=0)  # and a point three times
    track = Track.from_array(doubled)
    assert track.num_waypoints == clean.num_waypoints == 48
    assert track.length == pytest.approx(clean.length, abs=1e-12)
    assert np.array_equal(track.to_array(), rows)
    assert np.all(np.hypot(*np.diff(np.array(track.waypoints), axis=0).T) > 0)


def test_repeated_closing_row_is_dropped() -> None:
    rows = ring()
    track = Track.from_array(np.vstack([rows, rows[:1]]))  # closing row twice
    assert track.num_waypoints == 48 and track.closed
    assert np.array_equal(track.to_array(), rows)


def test_duplicate_start_and_end_of_an_open_route() -> None:
    rows = ring()[:20]
    track = Track.from_array(np.vstack([rows[:1], rows, rows[-1:]]))
    assert track.num_waypoints == 20
    assert not track.closed


def test_shared_duplicates_leave_no_zero_length_segments() -> None:
    for path in SHARED_FILES:
        track = Track.from_file(path)
        steps = np.hypot(*np.diff(np.array(track.waypoints), axis=0).T)
        assert np.all(steps > 1e-9), path.name
