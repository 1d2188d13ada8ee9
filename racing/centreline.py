"""The centre line of a track: segments, distances along it and projections onto it.

:class:`CentreLine` holds the geometry of the centre points alone (no borders): where a point
lies relative to the line (:class:`Location`), the point and heading at a distance along it, and
its curvature. :class:`racing.track.Track` builds on it with the borders, widths and the road.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


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


class CentreLine:
    """The polyline through ``centre`` (an ``(N, 2)`` array, metres) in the driving direction;
    a closed loop runs from the last point back to the first.

    ``cumulative[k]`` is the distance (metres) from the start to waypoint ``k``; ``length`` the
    whole line's length (metres); ``num_segments`` the number of centre segments.
    """

    def __init__(self, centre: np.ndarray, *, closed: bool) -> None:
        self.closed = closed
        self.centre = centre
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

    @property
    def num_waypoints(self) -> int:
        return len(self.centre)

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
