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
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import LinearRing, LineString, Polygon

MIN_DISTINCT_POINTS = 4
"""Fewest distinct centre points a track may have."""

MAX_COORDINATE_M = 1_000.0
"""Largest absolute coordinate accepted in a track file, metres."""

NPY_MAGIC = b"\x93NUMPY"

MIN_WIDTH_M = 0.2
"""Narrowest track accepted, metres (a DeepRacer car is about 0.2 m wide)."""


class TrackError(ValueError):
    """A track file or array is not a usable DeepRacer track; the message says why."""


@dataclass(frozen=True, slots=True)
class Location:
    """Where a point lies relative to the centre line, in the driving direction.

    ``segment`` is the index of the centre segment from waypoint ``segment`` to the next one;
    ``s`` the distance along the centre line from the start point (metres, 0..length);
    ``distance`` the distance to the centre line (metres); ``left`` whether the point lies left of
    the centre line; ``fraction`` the position along the segment (0..1).
    """

    segment: int
    fraction: float
    s: float
    distance: float
    left: bool
    x: float
    y: float


def parse_waypoints(data: bytes) -> np.ndarray:
    """The array in the bytes of a ``.npy`` file; :class:`TrackError` if they are not one.

    Only ``.npy`` is accepted: ``np.load`` would also open ``.npz``/zip archives, and pickles
    are never loaded.
    """
    if not data.startswith(NPY_MAGIC):
        raise TrackError("not a NumPy .npy array")
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError, MemoryError) as exc:
        raise TrackError(f"not a NumPy .npy array ({exc})") from exc


def load_waypoints(path: str | Path) -> np.ndarray:
    """Read a DeepRacer ``.npy`` track file, raising :class:`TrackError` when it is unusable."""
    path = Path(path)
    try:
        return parse_waypoints(path.read_bytes())
    except TrackError as exc:
        raise TrackError(f"{path.name}: {exc}") from exc


def _clean(array: np.ndarray) -> tuple[np.ndarray, bool]:
    """Validate the raw array; return (distinct rows without the closing row, closed?)."""
    if not isinstance(array, np.ndarray):
        raise TrackError("a track must be a NumPy array of shape (N, 6)")
    if array.ndim != 2 or array.shape[1] != 6:
        raise TrackError(
            f"a track array must have shape (N, 6): centre x,y | inner x,y | outer x,y; "
            f"got shape {array.shape}"
        )
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise TrackError(f"a track array must hold real numbers, not {array.dtype}")
    array = array.astype(np.float64)
    if not np.all(np.isfinite(array)):
        bad = int(np.argwhere(~np.isfinite(array))[0][0])
        raise TrackError(f"row {bad} holds NaN or infinity")
    if np.abs(array).max(initial=0.0) > MAX_COORDINATE_M:
        raise TrackError(f"coordinates beyond ±{MAX_COORDINATE_M:.0f} m: not a track in metres")
    closed = len(array) > 1 and bool(np.array_equal(array[0], array[-1]))
    rows = array[:-1] if closed else array
    # Drop consecutive duplicate centre points (they make zero-length segments).
    keep = np.ones(len(rows), dtype=bool)
    if len(rows) > 1:
        keep[1:] = np.any(np.abs(np.diff(rows[:, :2], axis=0)) > 1e-9, axis=1)
    rows = rows[keep]
    if closed and len(rows) > 1 and np.allclose(rows[0, :2], rows[-1, :2], atol=1e-9):
        rows = rows[:-1]
    if len(rows) < MIN_DISTINCT_POINTS:
        raise TrackError(
            f"a track needs at least {MIN_DISTINCT_POINTS} distinct waypoints; got {len(rows)}"
        )
    return rows, closed


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


class Track:
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
        self.closed = closed
        self.is_reversed = reverse
        self._rows = rows
        if reverse:
            # Same start point, opposite order: c0, c_{n-1}, ..., c1 for a loop.
            rows = np.concatenate([rows[:1], rows[:0:-1]]) if closed else rows[::-1]
        centre = np.ascontiguousarray(rows[:, 0:2])
        inner = np.ascontiguousarray(rows[:, 2:4])
        outer = np.ascontiguousarray(rows[:, 4:6])
        self.centre = centre
        if closed and abs(_signed_area(inner)) > abs(_signed_area(outer)):
            inner, outer = outer, inner  # "inner" is always the border nearer the loop's middle
        self.inner = inner
        self.outer = outer
        nxt = np.roll(centre, -1, axis=0) if closed else centre[1:]
        starts = centre if closed else centre[:-1]
        self._seg_start = starts
        self._seg_vec = nxt - starts
        self._seg_len = np.hypot(self._seg_vec[:, 0], self._seg_vec[:, 1])
        self._seg_len2 = np.maximum(self._seg_len**2, 1e-18)
        self._seg_heading = np.arctan2(self._seg_vec[:, 1], self._seg_vec[:, 0])
        self.cumulative = np.concatenate([[0.0], np.cumsum(self._seg_len)])
        self.length = float(self.cumulative[-1])
        self.num_segments = len(self._seg_len)
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
        rows, closed = _clean(np.asarray(array) if not isinstance(array, np.ndarray) else array)
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

    @property
    def num_waypoints(self) -> int:
        return len(self.centre)

    def on_track(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Whether each point (x, y) lies on the road surface (borders count as on)."""
        return shapely.intersects_xy(self.road, xs, ys)

    def locate(self, x: float, y: float, hint: int | None = None) -> Location:
        """Project a point onto the centre line.

        ``hint`` (a segment index from the previous step) restricts the search to nearby
        segments, which is much faster; the full search runs when the hint gives a poor match.
        """
        if hint is not None and self.num_segments > 24:
            idx = np.arange(hint - 6, hint + 7) % self.num_segments
            seg, frac, d2 = self._nearest(x, y, idx)
            if d2 < 1.0:  # within a metre of the centre line: trust the local search
                return self._location(seg, frac, d2, x, y)
        seg, frac, d2 = self._nearest(x, y, None)
        return self._location(seg, frac, d2, x, y)

    def locate_all(self, xs: np.ndarray, ys: np.ndarray) -> list[Location]:
        """:meth:`locate` (full search) for many points at once, vectorised over the points."""
        xs = np.asarray(xs, dtype=np.float64)[:, None]
        ys = np.asarray(ys, dtype=np.float64)[:, None]
        a, v = self._seg_start, self._seg_vec
        wx = xs - a[:, 0]
        wy = ys - a[:, 1]
        t = np.clip((wx * v[:, 0] + wy * v[:, 1]) / self._seg_len2, 0.0, 1.0)
        dx = wx - t * v[:, 0]
        dy = wy - t * v[:, 1]
        d2 = dx * dx + dy * dy
        best = np.argmin(d2, axis=1)
        rows = np.arange(len(best))
        return [
            self._location(
                int(k), float(t[i, k]), float(d2[i, k]), float(xs[i, 0]), float(ys[i, 0])
            )
            for i, k in zip(rows, best, strict=True)
        ]

    def _nearest(self, x: float, y: float, idx: np.ndarray | None) -> tuple[int, float, float]:
        a = self._seg_start if idx is None else self._seg_start[idx]
        v = self._seg_vec if idx is None else self._seg_vec[idx]
        l2 = self._seg_len2 if idx is None else self._seg_len2[idx]
        wx = x - a[:, 0]
        wy = y - a[:, 1]
        t = np.clip((wx * v[:, 0] + wy * v[:, 1]) / l2, 0.0, 1.0)
        dx = wx - t * v[:, 0]
        dy = wy - t * v[:, 1]
        d2 = dx * dx + dy * dy
        k = int(np.argmin(d2))
        seg = k if idx is None else int(idx[k])
        return seg, float(t[k]), float(d2[k])

    def _location(self, seg: int, frac: float, d2: float, x: float, y: float) -> Location:
        ax, ay = self._seg_start[seg]
        vx, vy = self._seg_vec[seg]
        cross = vx * (y - ay) - vy * (x - ax)
        s = float(self.cumulative[seg] + frac * self._seg_len[seg])
        return Location(
            segment=seg,
            fraction=frac,
            s=s if s < self.length else s - self.length,
            distance=math.sqrt(d2),
            left=bool(cross > 0.0),
            x=x,
            y=y,
        )

    def closest_waypoints(self, loc: Location) -> tuple[int, int]:
        """``[behind, ahead]`` waypoint indices around a located point."""
        ahead = loc.segment + 1
        if ahead >= self.num_waypoints:
            ahead = 0 if self.closed else self.num_waypoints - 1
        return loc.segment, ahead

    def width_at(self, loc: Location) -> float:
        nxt = (loc.segment + 1) % self.num_waypoints
        return float(
            self.widths[loc.segment] * (1 - loc.fraction) + self.widths[nxt] * loc.fraction
        )

    def heading_at(self, s: float) -> float:
        """Direction of the centre line at distance ``s`` from the start, radians."""
        return float(self._seg_heading[self.segment_at(s)])

    def segment_at(self, s: float) -> int:
        if self.closed:
            s %= self.length
        seg = int(np.searchsorted(self.cumulative, s, side="right")) - 1
        return min(max(seg, 0), self.num_segments - 1)

    def point_at(self, s: float, offset: float = 0.0) -> tuple[float, float]:
        """The point ``s`` metres along the centre line, shifted ``offset`` metres to the left."""
        if self.closed:
            s %= self.length
        else:
            s = min(max(s, 0.0), self.length)
        seg = self.segment_at(s)
        frac = (s - self.cumulative[seg]) / max(self._seg_len[seg], 1e-12)
        x, y = self._seg_start[seg] + frac * self._seg_vec[seg]
        if offset:
            h = self._seg_heading[seg]
            x -= offset * math.sin(h)
            y += offset * math.cos(h)
        return float(x), float(y)

    def stations(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment indices and fractions along them for distances ``s`` (metres), vectorised;
        a loop wraps ``s``, an open route clamps it."""
        s = np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)
        seg = np.clip(
            np.searchsorted(self.cumulative, s, side="right") - 1, 0, self.num_segments - 1
        )
        frac = (s - self.cumulative[seg]) / np.maximum(self._seg_len[seg], 1e-12)
        return seg, frac

    def points_at(
        self, seg: np.ndarray, frac: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`point_at` for many places at once, given by :meth:`stations`, shifted
        ``offsets`` metres left: ``x``, ``y`` (metres) and the centre line's heading (radians)."""
        heading = self._seg_heading[seg]
        x = self._seg_start[seg, 0] + frac * self._seg_vec[seg, 0] - offsets * np.sin(heading)
        y = self._seg_start[seg, 1] + frac * self._seg_vec[seg, 1] + offsets * np.cos(heading)
        return x, y, heading

    @cached_property
    def curvature(self) -> np.ndarray:
        """Unsigned curvature at each waypoint (1/m), smoothed over about half a metre."""
        h = self._seg_heading
        turn = np.diff(h, append=h[:1] if self.closed else h[-1:])
        turn = (turn + np.pi) % (2 * np.pi) - np.pi
        seg = self._seg_len
        span = 0.5 * (seg + (np.roll(seg, -1) if self.closed else np.append(seg[1:], seg[-1])))
        k = np.abs(turn) / np.maximum(span, 1e-6)
        width = max(1, int(round(0.5 / max(float(np.median(seg)), 1e-3))))
        kernel = np.ones(width) / width
        padded = (
            np.concatenate([k[-width:], k, k[:width]])
            if self.closed
            else np.pad(k, width, mode="edge")
        )
        smooth = np.convolve(padded, kernel, mode="same")[width:-width]
        out = np.zeros(self.num_waypoints)
        out[: len(smooth)] = smooth
        return out

    def curvature_ahead(self, s: float, distance: float) -> float:
        """Largest curvature (1/m) over the next ``distance`` metres of the centre line."""
        seg0 = self.segment_at(s)
        seg1 = self.segment_at(s + distance)
        if self.closed and seg1 < seg0:
            segs = np.r_[seg0 : self.num_segments, 0 : seg1 + 1]
        else:
            segs = np.arange(seg0, seg1 + 1)
        return float(self.curvature[segs].max()) if len(segs) else 0.0

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
