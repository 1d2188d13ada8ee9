"""Design the project's own race tracks and write them in DeepRacer's ``.npy`` format.

A design is a list of pieces driven from the start line: straights and turns. Each turn is a
circular arc entered and left through short clothoids (Euler spirals: curvature changing
linearly with distance), the way real circuits are built, so curvature never jumps and a
pure-pursuit controller sees no kinks. Working with exact arcs rather than a spline through
control points keeps every corner's radius exactly as designed.

The loop closes by construction: the turn angles add up to +360 degrees (counter-clockwise, the
native direction of DeepRacer files), and two straights marked ``adjust=True`` are lengthened or
shortened by the 2×2 linear solve that brings the end point back onto the start point.

The centre line is then resampled at uniform spacing (about 0.15-0.2 m, like DeepRacer files),
and the borders are offset by ±width/2 along the normals: columns 0:2 centre, 2:4 inner border
(the left one on a counter-clockwise loop: nearer the middle), 4:6 outer; the first row is
repeated at the end. Coordinates are rounded to a micrometre so the files are byte-stable.

Run ``python -m racing.trackgen`` to rewrite ``racing/tracks/*.npy`` and ``catalog.json``; the
output is the same bytes every run. ``python -m racing.trackgen --check`` only compares.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from racing.track import Track

TRACKS_DIR = Path(__file__).resolve().parent / "tracks"

STEP_M = 0.002
"""Integration step along turns, metres."""
DECIMALS = 6
"""Coordinates are rounded to 10**-DECIMALS metres (a micrometre)."""
MIN_RADIUS_M = 0.6
"""Tightest corner any design may have at the centre line, metres."""
BORDER_GAP_M = 0.25
"""Least floor between two different stretches of road, metres."""


@dataclass(frozen=True)
class Straight:
    """A straight ``length`` metres long; ``adjust=True`` lets the loop closure change it."""

    length: float
    adjust: bool = False


@dataclass(frozen=True)
class Turn:
    """A turn of ``angle`` degrees (positive = left) at ``radius`` metres.

    ``ease`` is the length of each clothoid leading into and out of the arc, metres; it is cut
    to 40% of the turn's arc length on short turns.
    """

    angle: float
    radius: float
    ease: float = 0.35


Piece = Straight | Turn


@dataclass(frozen=True)
class Design:
    """One track: pieces from the start line, road width and waypoint spacing (metres)."""

    track_id: str
    name: str
    description: str
    width: float
    spacing: float
    pieces: tuple[Piece, ...]
    heading: float = 0.0
    """Direction of the first piece, degrees anticlockwise from +x."""
    limits: dict[str, tuple[float, float]] = field(default_factory=dict, compare=False)
    """Expected ranges for ``length`` and ``min_radius`` (metres), checked on generation."""


class DesignError(ValueError):
    """A design does not make a valid track; the message says why."""


# ---------------------------------------------------------------------------------- geometry
def _turn_samples(turn: Turn, theta0: float) -> tuple[np.ndarray, np.ndarray]:
    """Headings at mid-steps and step lengths through one eased turn (relative to its start)."""
    angle = math.radians(turn.angle)
    kappa = math.copysign(1.0 / turn.radius, angle)
    arc_total = abs(angle) * turn.radius
    ease = min(turn.ease, 0.4 * arc_total)
    # Each clothoid turns ease * |kappa| / 2; the arc turns the rest.
    arc_len = arc_total - ease
    lengths = (ease, arc_len, ease)
    total = sum(lengths)
    n = max(8, int(math.ceil(total / STEP_M)))
    t = (np.arange(n) + 0.5) * (total / n)
    # Heading as a function of distance t into the turn.
    theta = np.empty(n)
    a = t < ease
    theta[a] = kappa * t[a] ** 2 / (2 * ease) if ease > 0 else 0.0
    b = (t >= ease) & (t < ease + arc_len)
    theta[b] = kappa * ease / 2 + kappa * (t[b] - ease)
    c = t >= ease + arc_len
    r = total - t[c]  # distance left to the end of the turn
    theta[c] = angle - (kappa * r**2 / (2 * ease) if ease > 0 else 0.0)
    return theta0 + theta, np.full(n, total / n)


def _steps(design: Design, lengths: Sequence[float]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Heading and length of every step around the loop, and which step each straight is."""
    theta = math.radians(design.heading)
    headings: list[np.ndarray] = []
    sizes: list[np.ndarray] = []
    straight_step: list[int] = []
    count = 0
    for piece, length in zip(design.pieces, lengths, strict=True):
        if isinstance(piece, Straight):
            straight_step.append(count)
            headings.append(np.array([theta]))
            sizes.append(np.array([length]))
            count += 1
        else:
            h, s = _turn_samples(piece, theta)
            headings.append(h)
            sizes.append(s)
            count += len(h)
            theta += math.radians(piece.angle)
    return np.concatenate(headings), np.concatenate(sizes), straight_step


def _closed_lengths(design: Design) -> list[float]:
    """Piece lengths (0 for turns) with the ``adjust`` straights set so the loop closes.

    Adding ``d`` metres to a straight moves everything after it by ``d`` along its heading, so
    the end point is linear in the adjustments: a 2×2 solve (or, with one adjust straight, a
    projection that must leave no miss) closes the loop exactly.
    """
    total_turn = sum(p.angle for p in design.pieces if isinstance(p, Turn))
    if abs(total_turn - 360.0) > 1e-9:
        raise DesignError(f"{design.track_id}: turns add up to {total_turn}°, not 360°")
    lengths = [p.length if isinstance(p, Straight) else 0.0 for p in design.pieces]
    adjust = [i for i, p in enumerate(design.pieces) if isinstance(p, Straight) and p.adjust]
    if len(adjust) not in (1, 2):
        raise DesignError(f"{design.track_id}: mark one or two straights adjust=True")
    headings, sizes, _ = _steps(design, lengths)
    gap = np.array([np.sum(sizes * np.cos(headings)), np.sum(sizes * np.sin(headings))])
    directions = np.array(
        [[math.cos(t), math.sin(t)] for t in (_heading_before(design, i) for i in adjust)]
    ).T
    if len(adjust) == 2 and abs(np.linalg.det(directions)) < 0.2:
        raise DesignError(f"{design.track_id}: the two adjust straights are nearly parallel")
    # One straight can only close a gap along itself (a symmetric design); two close any gap.
    change = np.linalg.lstsq(directions, -gap, rcond=None)[0]
    miss = float(np.hypot(*(directions @ change + gap)))
    if miss > 1e-6:
        raise DesignError(
            f"{design.track_id}: the loop misses its start by {miss:.3f} m; "
            "mark a second, non-parallel straight adjust=True"
        )
    for i, d in zip(adjust, change, strict=True):
        lengths[i] += float(d)
        if lengths[i] < 0.05:
            raise DesignError(
                f"{design.track_id}: closing the loop needs straight {i} to be "
                f"{lengths[i]:.2f} m long; rework the design"
            )
    return lengths


def _heading_before(design: Design, index: int) -> float:
    turned = sum(p.angle for p in design.pieces[:index] if isinstance(p, Turn))
    return math.radians(design.heading + turned)


@dataclass(frozen=True)
class CentreLine:
    """The closed centre line sampled finely: points ``(M+1, 2)``, headings and distances."""

    points: np.ndarray
    headings: np.ndarray
    s: np.ndarray
    lengths: tuple[float, ...]

    @property
    def length(self) -> float:
        return float(self.s[-1])


def centre_line(design: Design) -> CentreLine:
    """The closed centre line of ``design``, starting at the origin (first point repeated)."""
    lengths = _closed_lengths(design)
    headings, sizes, straight_step = _steps(design, lengths)
    steps = np.stack([sizes * np.cos(headings), sizes * np.sin(headings)], axis=1)
    points = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    points[-1] = points[0]  # closes to float precision; make it exact
    s = np.concatenate([[0.0], np.cumsum(sizes)])
    # Heading at each sample point: the step headings are taken mid-step, so average
    # neighbours (unwrapped), except along straights where the heading is exact.
    h = np.unwrap(headings)
    at_points = np.empty(len(points))
    at_points[1:-1] = 0.5 * (h[:-1] + h[1:])
    at_points[0] = h[0]
    for k in straight_step:
        at_points[k] = at_points[k + 1] = h[k]
    at_points[-1] = at_points[0] + 2 * math.pi  # one full turn anticlockwise
    return CentreLine(points, at_points, s, tuple(lengths))


def waypoints(design: Design) -> np.ndarray:
    """The DeepRacer ``(N+1, 6)`` array for ``design``: centre | inner | outer, closed.

    The track is centred on the origin (middle of its bounding box). Raises
    :class:`DesignError` when the road would overlap itself or leave the expected ranges.
    """
    line = centre_line(design)
    count = max(16, int(round(line.length / design.spacing)))
    s = np.arange(count) * (line.length / count)
    x = np.interp(s, line.s, line.points[:, 0])
    y = np.interp(s, line.s, line.points[:, 1])
    heading = np.interp(s, line.s, line.headings)
    left = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    centre = np.stack([x, y], axis=1)
    half = design.width / 2
    inner = centre + half * left  # counter-clockwise loop: left is the inside
    outer = centre - half * left
    rows = np.hstack([centre, inner, outer])
    borders = np.vstack([inner, outer])
    middle = 0.5 * (borders.min(axis=0) + borders.max(axis=0))
    rows -= np.tile(middle, 3)
    rows = np.round(rows, DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0
    rows = np.vstack([rows, rows[:1]])
    _check(design, rows)
    return rows


# ---------------------------------------------------------------------------------- checks
def min_radius(centre: np.ndarray) -> float:
    """Smallest radius of the circle through three consecutive points of a closed line, m.

    ``centre`` is ``(N, 2)``; a repeated closing point is ignored.
    """
    pts = np.asarray(centre, dtype=np.float64)
    if len(pts) > 1 and np.array_equal(pts[0], pts[-1]):
        pts = pts[:-1]
    a = np.roll(pts, 1, axis=0)
    c = np.roll(pts, -1, axis=0)
    ab = np.hypot(*(pts - a).T)
    bc = np.hypot(*(c - pts).T)
    ca = np.hypot(*(a - c).T)
    cross = np.abs((pts - a)[:, 0] * (c - pts)[:, 1] - (pts - a)[:, 1] * (c - pts)[:, 0])
    with np.errstate(divide="ignore"):
        radius = np.where(cross > 1e-15, ab * bc * ca / (2 * np.maximum(cross, 1e-300)), np.inf)
    return float(radius.min())


def min_border_gap(rows: np.ndarray, width: float) -> float:
    """Least distance between the road edges of two stretches of road that are not neighbours.

    Two centre points more than ``2.5 × (width + BORDER_GAP_M)`` apart along the loop belong
    to different stretches; their roads are ``distance - width`` apart. Metres.
    """
    centre = rows[:-1, :2] if np.array_equal(rows[0], rows[-1]) else rows[:, :2]
    seg = np.hypot(*np.diff(np.vstack([centre, centre[:1]]), axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    length = float(seg.sum())
    along = np.abs(s[:, None] - s[None, :])
    along = np.minimum(along, length - along)
    apart = np.hypot(*(centre[:, None, :] - centre[None, :, :]).transpose(2, 0, 1))
    far = along > 2.5 * (width + BORDER_GAP_M)
    if not far.any():
        return math.inf
    return float(apart[far].min() - width)


def _check(design: Design, rows: np.ndarray) -> None:
    track = Track.from_array(rows, track_id=design.track_id)  # raises on crossing borders
    track.reversed()
    if track.direction != "ccw":
        raise DesignError(f"{design.track_id}: the loop runs clockwise")
    radius = min_radius(rows[:, :2])
    if radius < MIN_RADIUS_M:
        raise DesignError(f"{design.track_id}: a corner of radius {radius:.2f} m is too tight")
    gap = min_border_gap(rows, design.width)
    if gap < BORDER_GAP_M:
        raise DesignError(f"{design.track_id}: two stretches of road are only {gap:.2f} m apart")
    figures = {"length": track.length, "min_radius": radius}
    xmin, ymin, xmax, ymax = track.bounds()
    figures["size_x"], figures["size_y"] = xmax - xmin, ymax - ymin
    for key, (low, high) in design.limits.items():
        if not low <= figures[key] <= high:
            raise DesignError(
                f"{design.track_id}: {key} is {figures[key]:.3f}, expected {low}..{high}"
            )


# ---------------------------------------------------------------------------------- designs
SUMMIT = Design(
    track_id="racecraft_summit",
    name="Racecraft Summit Loop",
    description=(
        "A compact loop on a 0.76 m road, sized like re:Invent 2018: a long start straight, "
        "a fast sweeper, a tight corner, a downhill S-bend and a hairpin."
    ),
    width=0.762,
    spacing=0.15,
    pieces=(
        Straight(3.0, adjust=True),
        Turn(70, 1.4),
        Straight(0.8, adjust=True),
        Turn(110, 0.75),
        Straight(1.4),
        Turn(60, 1.2),
        Straight(0.9),
        Turn(-60, 1.2),
        Straight(0.4),
        Turn(180, 0.7),
        Straight(0.8),
    ),
    limits={
        "length": (17.0, 18.0),
        "min_radius": (0.64, math.inf),
        "size_x": (0.0, 7.6),
        "size_y": (0.0, 5.1),
    },
)

OVAL = Design(
    track_id="racecraft_oval",
    name="Racecraft Oval",
    description="A wide stadium oval for first models: two long straights joined by gentle bends.",
    width=1.5,
    spacing=0.2,
    pieces=(
        Straight(2.1, adjust=True),
        Turn(180, 1.75, ease=0.8),
        Straight(4.2),
        Turn(180, 1.75, ease=0.8),
        Straight(2.1),
    ),
    limits={"length": (20.0, 22.0), "min_radius": (1.5, math.inf)},
)

TECHNICAL = Design(
    track_id="racecraft_technical",
    name="Racecraft Technical Circuit",
    description=(
        "A 35 m technical circuit on a 1.07 m road: a chicane, a hairpin, a double-apex "
        "right-hander and a run of esses reward precise lines."
    ),
    width=1.067,
    spacing=0.2,
    pieces=(
        Straight(4.0, adjust=True),
        Turn(90, 1.5),  # fast right-hand end of the main straight
        Straight(0.6, adjust=True),
        Turn(-30, 1.0),  # chicane
        Turn(60, 1.0),
        Turn(-30, 1.0),
        Straight(0.4),
        Turn(90, 1.1),
        Straight(2.3),
        Turn(180, 0.9),  # hairpin
        Straight(1.0),
        Turn(-90, 1.0),  # double-apex right-hander
        Straight(0.3),
        Turn(-90, 1.0),
        Straight(0.5),
        Turn(45, 1.2),  # esses
        Turn(-90, 1.2),
        Turn(45, 1.2),
        Straight(0.5),
        Turn(90, 1.0),
        Straight(0.1),
        Turn(90, 1.0),
        Straight(1.0),
    ),
    limits={
        "length": (30.0, 37.0),
        "min_radius": (0.6, math.inf),
        "size_x": (0.0, 12.2),
        "size_y": (0.0, 8.2),
    },
)

DESIGNS: tuple[Design, ...] = (SUMMIT, OVAL, TECHNICAL)


# ---------------------------------------------------------------------------------- files
def npy_bytes(rows: np.ndarray) -> bytes:
    """The ``.npy`` file contents for ``rows`` (float64, C order)."""
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(rows, dtype=np.float64), allow_pickle=False)
    return buffer.getvalue()


def catalog_json(designs: Sequence[Design] = DESIGNS) -> str:
    """``catalog.json``: ``{id: {"name": ..., "description": ...}}``, sorted, newline-ended."""
    entries = {d.track_id: {"name": d.name, "description": d.description} for d in designs}
    return json.dumps(entries, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def generated_files(designs: Sequence[Design] = DESIGNS) -> dict[str, bytes]:
    """File name → contents for every design plus ``catalog.json``."""
    files = {f"{d.track_id}.npy": npy_bytes(waypoints(d)) for d in designs}
    files["catalog.json"] = catalog_json(designs).encode()
    return files


def write_tracks(folder: Path = TRACKS_DIR, designs: Sequence[Design] = DESIGNS) -> list[Path]:
    """Write the generated files into ``folder``; return the paths whose contents changed."""
    return _write(folder, generated_files(designs))


def _stale(folder: Path, files: dict[str, bytes]) -> list[Path]:
    return [
        folder / n
        for n, d in files.items()
        if not (folder / n).is_file() or (folder / n).read_bytes() != d
    ]


def _write(folder: Path, files: dict[str, bytes]) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    changed = _stale(folder, files)
    for path in changed:
        path.write_bytes(files[path.name])
    return changed


def describe(design: Design) -> str:
    """One line of figures for ``design``: length, width, tightest radius, size, waypoints."""
    rows = waypoints(design)
    track = Track.from_array(rows, track_id=design.track_id)
    xmin, ymin, xmax, ymax = track.bounds()
    return (
        f"{design.track_id:22s} length {track.length:6.2f} m  width {track.width:.3f} m  "
        f"min radius {min_radius(rows[:, :2]):.2f} m  size {xmax - xmin:.2f} x "
        f"{ymax - ymin:.2f} m  waypoints {len(rows)}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m racing.trackgen", description="Regenerate the built-in track files."
    )
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 if stale")
    parser.add_argument("--out", type=Path, default=TRACKS_DIR, help="output folder")
    args = parser.parse_args(argv)
    for design in DESIGNS:
        print(describe(design))
    files = generated_files()
    if args.check:
        stale = _stale(args.out, files)
        for path in stale:
            print(f"stale: {path}", file=sys.stderr)
        return 1 if stale else 0
    for path in _write(args.out, files):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
