"""Race tracks built from DeepRacer waypoint arrays.

A DeepRacer track file is a NumPy ``.npy`` array of shape ``(N, 6)``, one row per waypoint:
centre ``x, y`` | inner border ``x, y`` | outer border ``x, y``, in metres. The route is a closed
loop when the first row equals the last. Consecutive duplicate centre points are dropped on load
(DeepRacer's community loader does the same), so indices refer to the cleaned list.

A :class:`Track` is one driving direction over one such array. ``Track.reversed()`` gives the
other direction: the same start point, the waypoints in the opposite order. Everything a reward
function sees (``waypoints``, ``closest_waypoints``, left/right, progress) is expressed in the
driving direction.

Widths are measured across the track (distance from the centre point to the inner border
polyline plus to the outer border polyline), because the oldest DeepRacer files do not pair
row k of the inner border with row k of the outer one.

Reading and cleaning the files is racing/waypoints.py; the centre line's geometry (projection,
distances along it, curvature) is racing/centreline.py, which :class:`Track` builds on.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import LinearRing, LineString, Polygon

from racing.centreline import CentreLine, Location
from racing.waypoints import (
    MAX_COORDINATE_M,
    MIN_DISTINCT_POINTS,
    NPY_MAGIC,
    TrackError,
    clean_waypoints,
    load_waypoints,
    parse_waypoints,
)

__all__ = [
    "MAX_COORDINATE_M",
    "MIN_DISTINCT_POINTS",
    "MIN_WIDTH_M",
    "NPY_MAGIC",
    "Location",
    "Track",
    "TrackError",
    "load_waypoints",
    "parse_waypoints",
]

MIN_WIDTH_M = 0.2
"""Narrowest track accepted, metres (a DeepRacer car is about 0.2 m wide)."""


def _border_distances(points: np.ndarray, border: np.ndarray, closed: bool) -> np.ndarray:
    """Each point's distance to the polyline through ``border`` (closed: back to its start).

    The same numbers as ``shapely.distance(points, LineString(border))``, through an R-tree of
    the border's segments: O(n log n) instead of every point against every segment (a dense
    2 MB track file of 40,000 waypoints took minutes that way)."""
    ring = np.vstack([border, border[:1]]) if closed else border
    segments = shapely.linestrings(np.stack([ring[:-1], ring[1:]], axis=1))
    which, dist = shapely.STRtree(segments).query_nearest(points, return_distance=True)
    out = np.full(len(points), np.inf)
    np.minimum.at(out, which[0], dist)  # ties list a point more than once
    return out


def _signed_area(points: np.ndarray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


class Track(CentreLine):
    """One driving direction over a DeepRacer waypoint array.

    Build with :meth:`from_array` or :meth:`from_file`; get the other direction with
    :meth:`reversed`. Raises :class:`TrackError` for unusable input: wrong shape, NaN, too few
    points, crossing or self-intersecting borders, or a track too narrow for the car.
    """

    def __init__(
        self,
        rows: np.ndarray,
        *,
        closed: bool,
        track_id: str,
        name: str,
        reverse: bool = False,
        validate: bool = True,
    ) -> None:
        self.track_id = track_id
        self.name = name or track_id
        self.is_reversed = reverse
        self._rows = rows
        if reverse:
            # Same start point, opposite order: c0, c_{n-1}, ..., c1 for a loop.
            rows = np.concatenate([rows[:1], rows[:0:-1]]) if closed else rows[::-1]
        centre = np.ascontiguousarray(rows[:, 0:2])
        inner = np.ascontiguousarray(rows[:, 2:4])
        outer = np.ascontiguousarray(rows[:, 4:6])
        super().__init__(centre, closed=closed)
        if closed and abs(_signed_area(inner)) > abs(_signed_area(outer)):
            inner, outer = outer, inner  # "inner" is always the border nearer the loop's middle
        self.inner = inner
        self.outer = outer
        if validate:
            self._validate()
        self.widths = self._perpendicular_widths()
        self.width = float(np.mean(self.widths))
        area = _signed_area(centre) if closed else 0.0
        self.direction = "open" if not closed else ("ccw" if area > 0 else "cw")
        self._waypoint_tuples = tuple(
            (float(x), float(y)) for x, y in (np.vstack([centre, centre[:1]]) if closed else centre)
        )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_array(
        cls, array: np.ndarray, *, track_id: str = "", name: str = "", reverse: bool = False
    ) -> Track:
        rows, closed = clean_waypoints(
            np.asarray(array) if not isinstance(array, np.ndarray) else array
        )
        return cls(rows, closed=closed, track_id=track_id, name=name, reverse=reverse)

    @classmethod
    def from_file(cls, path: str | Path, *, name: str = "", reverse: bool = False) -> Track:
        path = Path(path)
        return cls.from_array(
            load_waypoints(path), track_id=path.stem, name=name or path.stem, reverse=reverse
        )

    def reversed(self) -> Track:
        """The same track driven the other way round (not possible on an open route)."""
        if not self.closed:
            raise TrackError(f"{self.track_id}: an open route can only be driven one way")
        return Track(
            self._rows,
            closed=True,
            track_id=self.track_id,
            name=self.name,
            reverse=not self.is_reversed,
            validate=False,
        )

    def in_direction(self, direction: str) -> Track:
        """This track driven ``'ccw'`` or ``'cw'`` (``'native'`` keeps the file's order)."""
        if direction not in ("ccw", "cw", "native"):
            raise TrackError(f"direction must be 'ccw', 'cw' or 'native', not {direction!r}")
        if direction == "native":
            return self if not self.is_reversed else self.reversed()
        if not self.closed:
            raise TrackError(f"{self.track_id}: an open route has no direction to choose")
        return self if self.direction == direction else self.reversed()

    @property
    def native_direction(self) -> str:
        if not self.closed:
            return "open"
        flip = {"ccw": "cw", "cw": "ccw"}
        return flip[self.direction] if self.is_reversed else self.direction

    def to_array(self) -> np.ndarray:
        """The (N, 6) array in the file's own order, closed loops repeating the first row."""
        rows = self._rows
        return np.vstack([rows, rows[:1]]) if self.closed else rows.copy()

    # ------------------------------------------------------------------ validation
    def _validate(self) -> None:
        inner_line = self._border_geometry(self.inner)
        outer_line = self._border_geometry(self.outer)
        centre_line = self._border_geometry(self.centre)
        for label, line in (("inner", inner_line), ("outer", outer_line), ("centre", centre_line)):
            if not line.is_simple:
                raise TrackError(f"the {label} line crosses itself")
        if inner_line.intersects(outer_line):
            raise TrackError("the inner and outer borders cross each other")
        if self.closed and not Polygon(self.outer).contains(Polygon(self.inner)):
            raise TrackError("the inner border does not lie inside the outer border")
        if self.length <= 0:
            raise TrackError("the centre line has no length")

    def _border_geometry(self, points: np.ndarray) -> LineString:
        return LinearRing(points) if self.closed else LineString(points)

    def _perpendicular_widths(self) -> np.ndarray:
        pts = shapely.points(self.centre)
        width = _border_distances(pts, self.inner, self.closed) + _border_distances(
            pts, self.outer, self.closed
        )
        if np.median(width) < MIN_WIDTH_M:
            raise TrackError(
                f"the track is {np.median(width):.2f} m wide; at least {MIN_WIDTH_M} m is needed"
            )
        return np.asarray(width, dtype=np.float64)

    # ------------------------------------------------------------------ geometry
    @cached_property
    def road(self) -> Polygon:
        """The drivable surface: inside the outer border and outside the inner one."""
        if self.closed:
            road = Polygon(self.outer, holes=[self.inner])
        else:
            road = Polygon(np.vstack([self.inner, self.outer[::-1]]))
        if not road.is_valid:
            road = road.buffer(0)
        shapely.prepare(road)
        return road

    @property
    def waypoints(self) -> list[tuple[float, float]]:
        """Centre points in the driving direction; a loop repeats the first at the end."""
        return list(self._waypoint_tuples)

    def on_track(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Whether each point (x, y) lies on the road surface (borders count as on)."""
        return shapely.intersects_xy(self.road, xs, ys)

    def width_at(self, loc: Location) -> float:
        nxt = (loc.segment + 1) % self.num_waypoints
        return float(
            self.widths[loc.segment] * (1 - loc.fraction) + self.widths[nxt] * loc.fraction
        )

    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` over both borders, metres."""
        pts = np.vstack([self.inner, self.outer, self.centre])
        return (
            float(pts[:, 0].min()),
            float(pts[:, 1].min()),
            float(pts[:, 0].max()),
            float(pts[:, 1].max()),
        )

    def __repr__(self) -> str:
        return (
            f"Track({self.track_id!r}, {self.direction}, length={self.length:.2f} m, "
            f"width={self.width:.3f} m, waypoints={self.num_waypoints})"
        )
