"""Track previews: a PNG of the requested width, the same bytes every time, arrow and start line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from racing.drawing import BOT_RGB, BOX_RGB
from racing.preview import (
    ARROW_RGB,
    MARGIN_M,
    race_objects,
    render_preview,
    render_preview_png,
    render_race_preview_png,
)
from racing.race import RaceConfig
from racing.track import Track
from racing.tracks import DEEPRACER_DIR, TrackCatalog

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def summit() -> Track:
    return TrackCatalog().load("racecraft_summit")


def decode(png: bytes) -> np.ndarray:
    """PNG bytes to an RGB array."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.ndim == 3 and image.shape[2] == 3
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def arrow_pixels(image: np.ndarray) -> np.ndarray:
    """(row, column) of pixels close to the arrow colour."""
    diff = np.abs(image.astype(int) - np.array(ARROW_RGB)).sum(axis=2)
    return np.argwhere(diff < 40)


@pytest.mark.parametrize("width_px", [64, 200, 480, 641])
def test_png_of_the_requested_width(summit: Track, width_px: int) -> None:
    png = render_preview_png(summit, width_px=width_px)
    assert png.startswith(PNG_SIGNATURE)
    image = decode(png)
    assert image.shape[1] == width_px
    xmin, ymin, xmax, ymax = summit.bounds()
    aspect = (ymax - ymin + 2 * MARGIN_M) / (xmax - xmin + 2 * MARGIN_M)
    assert image.shape[0] == pytest.approx(width_px * aspect, abs=1)


def test_default_width(summit: Track) -> None:
    assert decode(render_preview_png(summit)).shape[1] == 480


def test_deterministic(summit: Track) -> None:
    assert render_preview_png(summit) == render_preview_png(summit)
    fresh = TrackCatalog().load("racecraft_summit")
    assert render_preview_png(fresh) == render_preview_png(summit)


def test_png_holds_the_rendered_image(summit: Track) -> None:
    assert np.array_equal(decode(render_preview_png(summit)), render_preview(summit))


def test_arrow_points_the_driving_way(summit: Track) -> None:
    """The arrow sits just past the start line, on the side the car drives towards."""
    for track in (summit, summit.reversed()):
        image = render_preview(track, width_px=480)
        red = arrow_pixels(image)
        assert len(red) > 20
        rows, cols = red.mean(axis=0)
        xmin, _, xmax, ymax = track.bounds()
        px_per_m = 480 / (xmax - xmin + 2 * MARGIN_M)
        start_col = (track.centre[0][0] - xmin + MARGIN_M) * px_per_m
        ahead = track.point_at(0.5)[0] - track.centre[0][0]  # x grows to the right
        assert np.sign(cols - start_col) == np.sign(ahead)
        assert (ymax + MARGIN_M - track.centre[0][1]) * px_per_m == pytest.approx(rows, abs=8)


def test_start_line_is_chequered(summit: Track) -> None:
    image = render_preview(summit, width_px=480)
    xmin, _, xmax, ymax = summit.bounds()
    px_per_m = 480 / (xmax - xmin + 2 * MARGIN_M)
    x, y = summit.centre[0]
    col = int((x - xmin + MARGIN_M) * px_per_m)
    row = int((ymax + MARGIN_M - y) * px_per_m)
    patch = image[row - 15 : row + 15, col - 6 : col + 6].reshape(-1, 3).astype(int)
    assert (patch.sum(axis=1) < 120).any()  # dark squares
    assert (patch.sum(axis=1) > 650).any()  # light squares


@pytest.mark.parametrize("track_id", ["racecraft_summit", "racecraft_oval", "racecraft_technical"])
def test_every_builtin_track_renders(track_id: str) -> None:
    image = decode(render_preview_png(TrackCatalog().load(track_id), width_px=320))
    assert image.shape[1] == 320
    # Mostly floor and road, cropped close: the road covers a fair share of the picture.
    road = (np.abs(image.astype(int) - (52, 54, 60)).sum(axis=2) < 30).mean()
    assert 0.1 < road < 0.8


def test_open_route_renders() -> None:
    track = Track.from_file(DEEPRACER_DIR / "Straight_track.npy")
    image = decode(render_preview_png(track, width_px=300))
    assert image.shape[1] == 300
    assert len(arrow_pixels(image)) > 10


@pytest.mark.parametrize("width_px", [0, 8, 100_000])
def test_unreasonable_width_is_refused(summit: Track, width_px: int) -> None:
    with pytest.raises(ValueError, match="width_px"):
        render_preview_png(summit, width_px=width_px)


# ------------------------------------------------------------------ a race's objects
def colour_blobs(image: np.ndarray, rgb: tuple[int, int, int]) -> list[tuple[float, float]]:
    """Centres (column, row) of the connected patches of pixels close to ``rgb``."""
    mask = (np.abs(image.astype(int) - np.array(rgb)).sum(axis=2) < 30).astype(np.uint8)
    count, _, stats, centres = cv2.connectedComponentsWithStats(mask)
    return [tuple(c) for c, s in zip(centres[1:], stats[1:], strict=True) if s[4] >= 4]


@pytest.fixture(scope="module")
def oval() -> Track:
    return TrackCatalog().load("racecraft_oval")


def test_a_race_preview_draws_each_box_where_the_simulator_puts_it(oval: Track) -> None:
    config = RaceConfig(race_type="OBJECT_AVOIDANCE", object_positions=((0.25, 1), (0.6, -1)))
    boxes = race_objects(oval, config)
    image = decode(render_race_preview_png(oval, config, width_px=480))
    blobs = colour_blobs(image, BOX_RGB)
    assert len(blobs) == len(boxes) == 2
    # The map spans the track's bounds plus the margin, north up: world x to the right,
    # world y upwards (pixel rows downwards).
    xmin, ymin, xmax, ymax = oval.bounds()
    px_per_m = 480 / (xmax - xmin + 2 * MARGIN_M)
    expected = sorted(
        ((b.x - xmin + MARGIN_M) * px_per_m, (ymax + MARGIN_M - b.y) * px_per_m) for b in boxes
    )
    for (col, row), (want_col, want_row) in zip(sorted(blobs), expected, strict=True):
        assert abs(col - want_col) < 3 and abs(row - want_row) < 3
    assert not colour_blobs(render_preview(oval, 480), BOX_RGB)  # the plain map has none


def test_a_head_to_bot_preview_shows_every_bot_car_and_a_time_trial_none(oval: Track) -> None:
    bots = RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=3)
    assert len(colour_blobs(decode(render_race_preview_png(oval, bots)), BOT_RGB)) == 3
    assert render_race_preview_png(oval, RaceConfig()) == render_preview_png(oval)


def test_random_boxes_show_the_draw_of_the_seed(oval: Track) -> None:
    config = RaceConfig(race_type="OBJECT_AVOIDANCE", number_of_objects=3, randomize_objects=True)
    assert render_race_preview_png(oval, config, seed=1) == render_race_preview_png(
        oval, config, seed=1
    )
    assert render_race_preview_png(oval, config, seed=1) != render_race_preview_png(
        oval, config, seed=2
    )


def test_objects_that_do_not_fit_are_refused_in_words(oval: Track) -> None:
    config = RaceConfig(race_type="OBJECT_AVOIDANCE", number_of_objects=6, min_object_gap_m=9.0)
    with pytest.raises(ValueError, match="do not fit"):
        render_race_preview_png(oval, config)
