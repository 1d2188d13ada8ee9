"""DeepRacer waypoint arrays: reading ``.npy`` track files and cleaning their rows.

A DeepRacer track file is a NumPy ``.npy`` array of shape ``(N, 6)``, one row per waypoint:
centre ``x, y`` | inner border ``x, y`` | outer border ``x, y``, in metres. The route is a closed
loop when the first row equals the last. Consecutive duplicate centre points are dropped on load
(DeepRacer's community loader does the same), so indices refer to the cleaned list.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

MIN_DISTINCT_POINTS = 4
"""Fewest distinct centre points a track may have."""

MAX_COORDINATE_M = 1_000.0
"""Largest absolute coordinate accepted in a track file, metres."""

NPY_MAGIC = b"\x93NUMPY"


class TrackError(ValueError):
    """A track file or array is not a usable DeepRacer track; the message says why."""


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


def clean_waypoints(array: np.ndarray) -> tuple[np.ndarray, bool]:
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
