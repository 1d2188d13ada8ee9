"""Track widths through an R-tree of the border's segments: the same numbers as shapely's plain
distance to the border line, on every built-in track and on a dense one."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from racing.track import Track, _border_distances
from racing.tracks import TrackCatalog


def _dense_ellipse(n: int) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = [
        np.stack([a * np.cos(t), b * np.sin(t)], 1) for a, b in ((5, 3), (4.5, 2.5), (5.5, 3.5))
    ]
    return np.hstack(ring)


@pytest.mark.parametrize("track_id", TrackCatalog().ids())
def test_border_distances_match_shapely(track_id: str) -> None:
    track = TrackCatalog().load(track_id)
    points = shapely.points(track.centre)
    for border in (track.inner, track.outer):
        plain = shapely.distance(points, track._border_geometry(border))
        assert np.allclose(_border_distances(points, border, track.closed), plain, rtol=0,
                           atol=1e-12)  # fmt: skip


def test_a_dense_track_gets_the_same_widths() -> None:
    track = Track.from_array(_dense_ellipse(4000))  # 4,000 waypoints: once O(n²), now O(n log n)
    points = shapely.points(track.centre)
    plain = shapely.distance(points, track._border_geometry(track.inner)) + shapely.distance(
        points, track._border_geometry(track.outer)
    )
    assert np.allclose(track.widths, plain, rtol=0, atol=1e-12)
    assert 0.9 < track.width < 1.1
