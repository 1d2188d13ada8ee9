"""The built-in tracks: generated deterministically, in range, drivable, valid both ways round."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from racing import trackgen
from racing.track import Track
from racing.trackgen import DESIGNS, Design, DesignError, Straight, Turn
from racing.tracks import BUILTIN_DIR

# id: (length range m, width m, largest bounding box m, tightest radius m)
REQUIREMENTS = {
    "racecraft_summit": ((17.0, 18.0), 0.76, (7.6, 5.1), 0.64),
    "racecraft_oval": ((20.0, 22.0), 1.5, (11.0, 6.0), 1.5),
    "racecraft_technical": ((30.0, 37.0), 1.067, (12.2, 8.2), 0.8),
}
WHEELBASE_M = 0.165
"""A 1/18 DeepRacer car's wheelbase, for the kinematic pure-pursuit check below."""
MAX_STEER_RAD = math.radians(30)


def load_rows(track_id: str) -> np.ndarray:
    return np.load(BUILTIN_DIR / f"{track_id}.npy", allow_pickle=False)


def circumradii(points: np.ndarray) -> np.ndarray:
    """Radius of the circle through each point and its two neighbours on a closed line."""
    a, b, c = np.roll(points, 1, axis=0), points, np.roll(points, -1, axis=0)
    ab, bc, ca = (np.linalg.norm(u - v, axis=1) for u, v in ((a, b), (b, c), (c, a)))
    u, v = b - a, c - b
    twice_area = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    with np.errstate(divide="ignore"):
        return ab * bc * ca / (2 * twice_area)


def test_designs_cover_the_catalogue() -> None:
    assert {d.track_id for d in DESIGNS} == set(REQUIREMENTS)


def test_files_are_what_the_generator_makes_now() -> None:
    expected = trackgen.generated_files()
    on_disk = {p.name for p in BUILTIN_DIR.iterdir() if p.suffix in (".npy", ".json")}
    assert on_disk == set(expected)
    for name, data in expected.items():
        assert (BUILTIN_DIR / name).read_bytes() == data, (
            f"racing/tracks/{name} is stale: run `python -m racing.trackgen`"
        )


def test_generation_is_deterministic() -> None:
    first = {d.track_id: trackgen.waypoints(d) for d in DESIGNS}
    second = {d.track_id: trackgen.waypoints(d) for d in DESIGNS}
    for track_id, rows in first.items():
        assert np.array_equal(rows, second[track_id])
        assert np.array_equal(rows, load_rows(track_id))


def test_write_tracks_writes_only_changes(tmp_path: Path) -> None:
    written = trackgen.write_tracks(tmp_path)
    assert sorted(p.name for p in written) == sorted(trackgen.generated_files())
    assert trackgen.write_tracks(tmp_path) == []
    assert trackgen.main(["--check", "--out", str(tmp_path)]) == 0
    (tmp_path / "racecraft_oval.npy").write_bytes(b"stale")
    assert trackgen.main(["--check", "--out", str(tmp_path)]) == 1
    assert trackgen.main(["--out", str(tmp_path)]) == 0
    assert trackgen.main(["--check", "--out", str(tmp_path)]) == 0


@pytest.mark.parametrize("track_id", list(REQUIREMENTS))
def test_file_format(track_id: str) -> None:
    rows = load_rows(track_id)
    assert rows.dtype == np.float64 and rows.ndim == 2 and rows.shape[1] == 6
    assert np.array_equal(rows[0], rows[-1])  # closed the DeepRacer way
    centre, inner, outer = rows[:-1, 0:2], rows[:-1, 2:4], rows[:-1, 4:6]
    # The centre is the midpoint of its border points, and rows pair across the road.
    assert np.allclose(centre, (inner + outer) / 2, atol=2e-6)
    width = REQUIREMENTS[track_id][1]
    assert np.allclose(np.linalg.norm(inner - outer, axis=1), width, atol=0.01)
    # Inner = the border nearer the middle of the loop (smaller area).
    track = Track.from_array(rows)
    assert np.array_equal(track.inner, inner)
    steps = np.linalg.norm(np.diff(rows[:, :2], axis=0), axis=1)
    assert steps.min() >= 0.1 and steps.max() <= 0.3
    assert steps.max() - steps.min() < 0.002  # uniform along the curve; chords a bit shorter
    xmin, ymin, xmax, ymax = track.bounds()
    assert abs(xmin + xmax) < 1e-5 and abs(ymin + ymax) < 1e-5  # centred on the origin


@pytest.mark.parametrize("track_id", list(REQUIREMENTS))
def test_figures_in_range(track_id: str) -> None:
    (low, high), width, (max_x, max_y), tightest = REQUIREMENTS[track_id]
    rows = load_rows(track_id)
    track = Track.from_array(rows)
    assert low <= track.length <= high
    assert track.width == pytest.approx(width, abs=0.005)
    xmin, ymin, xmax, ymax = track.bounds()
    assert xmax - xmin <= max_x and ymax - ymin <= max_y
    radius = circumradii(rows[:-1, :2]).min()
    assert radius >= max(tightest, trackgen.MIN_RADIUS_M)
    assert radius == pytest.approx(trackgen.min_radius(rows[:, :2]))
    # The inner border never folds back on itself: its own radius stays positive.
    assert radius - width / 2 > 0.2


@pytest.mark.parametrize("track_id", list(REQUIREMENTS))
def test_valid_both_ways_round(track_id: str) -> None:
    rows = load_rows(track_id)
    native = Track.from_array(rows, track_id=track_id)
    backwards = Track.from_array(rows, track_id=track_id, reverse=True)
    assert native.direction == "ccw" and backwards.direction == "cw"
    assert backwards.length == pytest.approx(native.length)
    flipped = rows[::-1].copy()  # a file written clockwise is a valid track too
    assert Track.from_array(flipped).direction == "cw"


@pytest.mark.parametrize("track_id", list(REQUIREMENTS))
def test_stretches_of_road_keep_apart(track_id: str) -> None:
    rows = load_rows(track_id)
    width = REQUIREMENTS[track_id][1]
    assert trackgen.min_border_gap(rows, width) >= trackgen.BORDER_GAP_M


def drive_a_lap(track: Track, speed: float, lookahead: float, dt: float = 0.02) -> float:
    """Pure pursuit on a kinematic bicycle; return the largest distance from the centre line."""
    x, y = track.point_at(0.0)
    heading = track.heading_at(0.0)
    travelled, worst, hint = 0.0, 0.0, None
    loc = track.locate(x, y)
    while travelled < track.length + 1.0:
        target = np.array(track.point_at(loc.s + lookahead))
        dx, dy = target - (x, y)
        alpha = math.atan2(dy, dx) - heading
        steer = math.atan2(2 * WHEELBASE_M * math.sin(alpha), math.hypot(dx, dy))
        steer = max(-MAX_STEER_RAD, min(MAX_STEER_RAD, steer))
        x += speed * math.cos(heading) * dt
        y += speed * math.sin(heading) * dt
        heading += speed / WHEELBASE_M * math.tan(steer) * dt
        travelled += speed * dt
        loc = track.locate(x, y, hint=hint)
        hint = loc.segment
        worst = max(worst, loc.distance)
    return worst


@pytest.mark.parametrize("direction", ["ccw", "cw"])
@pytest.mark.parametrize("track_id", list(REQUIREMENTS))
def test_pure_pursuit_laps(track_id: str, direction: str) -> None:
    track = Track.from_array(load_rows(track_id)).in_direction(direction)
    worst = drive_a_lap(track, speed=1.5, lookahead=0.5)
    # The 0.2 m wide car keeps all four wheels on the road.
    assert worst + 0.1 < track.width / 2


# ------------------------------------------------------------------ the design language
def design(*pieces: Straight | Turn, **kw: object) -> Design:
    return Design("test", "Test", "A test.", width=0.6, spacing=0.2, pieces=pieces, **kw)


SQUARE = (
    Straight(3.0, adjust=True),
    Turn(90, 1.0),
    Straight(2.0, adjust=True),
    Turn(90, 1.0),
    Straight(3.0),
    Turn(90, 1.0),
    Straight(2.0),
    Turn(90, 1.0),
)


def test_closure_fixes_the_adjust_straights() -> None:
    lopsided = list(SQUARE)
    lopsided[4] = Straight(3.7)
    line = trackgen.centre_line(design(*lopsided))
    assert line.lengths[0] == pytest.approx(3.7, abs=1e-9)
    assert line.lengths[2] == pytest.approx(2.0, abs=1e-9)
    assert np.array_equal(line.points[0], line.points[-1])


def test_turns_must_add_up_to_a_full_circle() -> None:
    with pytest.raises(DesignError, match="turns add up to 270"):
        trackgen.waypoints(design(*SQUARE[:-1]))


def test_clockwise_design_is_refused() -> None:
    clockwise = [Turn(-p.angle, p.radius) if isinstance(p, Turn) else p for p in SQUARE]
    with pytest.raises(DesignError, match="not 360"):
        trackgen.waypoints(design(*clockwise))


def test_tight_corner_is_refused() -> None:
    tight = [Turn(90, 0.5) if isinstance(p, Turn) else p for p in SQUARE]
    with pytest.raises(DesignError, match="too tight"):
        trackgen.waypoints(design(*tight))


def test_parallel_adjust_straights_are_refused() -> None:
    parallel = list(SQUARE)
    parallel[2], parallel[4] = Straight(2.0), Straight(3.0, adjust=True)
    with pytest.raises(DesignError, match="nearly parallel"):
        trackgen.waypoints(design(*parallel))


def test_stretches_too_close_are_refused() -> None:
    # A paper-clip oval whose straights run 1.4 m apart on a 1.2 m road: 0.2 m of grass.
    clip = (Straight(4.0, adjust=True), Turn(180, 0.7), Straight(4.0), Turn(180, 0.7))
    narrow = Design("test", "Test", "A test.", width=1.2, spacing=0.2, pieces=clip)
    with pytest.raises(DesignError, match=r"only 0\.2\d m apart"):
        trackgen.waypoints(narrow)


def test_limits_are_enforced() -> None:
    with pytest.raises(DesignError, match="length is .* expected 50"):
        trackgen.waypoints(design(*SQUARE, limits={"length": (50.0, 60.0)}))
