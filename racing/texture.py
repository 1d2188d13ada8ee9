"""Top-down pictures of a track: the ground texture that cameras look at.

The fast camera projects this flat picture with a homography instead of ray-tracing a 3-D scene,
so everything painted on the ground (asphalt, white border lines, the dashed centre line, the
start line) is drawn here once per track, at a fixed resolution in metres per pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from racing.track import Track

# Colours (RGB) of DeepRacer's simulated track (Gazebo), measured on AWS camera frames: grass,
# blue-black asphalt, off-white borders, an orange centre line. The camera sees them in grayscale
# through DeepRacer's RGB -> Y conversion (about 133, 53, 208 and 139 of 255).
FLOOR_RGB = (106, 150, 116)
ROAD_RGB = (41, 55, 72)
BORDER_RGB = (207, 209, 204)
CENTRE_RGB = (209, 128, 8)
START_RGB = (207, 209, 204)
WALL_RGB = (10, 20, 23)
"""DeepRacer's dark walls round the track (gray ~17; 2-25 on its frames): what the camera sees
beyond the ground picture and above the ground (:func:`racing.sensors._backdrop`)."""

BORDER_LINE_M = 0.076
"""Width of the white border lines, metres, painted inside the road. On DeepRacer's frames a
border is 0.123 of the asphalt between the borders at the same image row: 3 inches of a
0.762 m track (DeepRacer's track_width, borders included)."""
CENTRE_LINE_M = 0.03
"""Width of the centre line, metres (0.05 of the asphalt on DeepRacer's frames)."""
CENTRE_DASH_M = 0.05
"""Length of each dash of the centre line (and of the gap between dashes), metres. On
DeepRacer's frames a dash covers 0.42-0.48 of its period, and the period is 4-10 cm on the
ground (it depends on the simulator's lens, which the frames alone do not settle)."""
MARGIN_M = 1.0
"""Floor shown around the track's bounding box, metres."""

_SHIFT = 4  # fixed-point bits for sub-pixel drawing
_SCALE = 1 << _SHIFT


@dataclass(frozen=True)
class GroundTexture:
    """A top-down picture of the ground.

    ``image`` is ``(H, W)`` uint8 (grayscale) or ``(H, W, 3)`` uint8 (RGB). Pixel ``(u, v)``
    (column, row) covers the world point ``x = x0 + (u + 0.5) * resolution``,
    ``y = y1 - (v + 0.5) * resolution``: rows run from the top (largest y) down.
    """

    image: np.ndarray
    x0: float
    y1: float
    resolution: float

    @property
    def world_to_pixel(self) -> np.ndarray:
        """3×3 matrix mapping homogeneous world ``(x, y, 1)`` to pixel ``(u, v, 1)``."""
        r = self.resolution
        return np.array(
            [[1 / r, 0, -self.x0 / r - 0.5], [0, -1 / r, self.y1 / r - 0.5], [0, 0, 1]],
            dtype=np.float64,
        )

    @property
    def pixel_to_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_to_pixel)

    def to_pixels(self, points: np.ndarray) -> np.ndarray:
        """World points ``(N, 2)`` to pixel coordinates ``(N, 2)`` (float)."""
        pts = np.asarray(points, dtype=np.float64)
        u = (pts[:, 0] - self.x0) / self.resolution - 0.5
        v = (self.y1 - pts[:, 1]) / self.resolution - 0.5
        return np.stack([u, v], axis=1)

    @property
    def floor_value(self) -> int | tuple[int, int, int]:
        """What lies beyond the picture (``MARGIN_M`` of grass round the track): DeepRacer's
        dark walls, whose foot the camera sees a few rows below the horizon."""
        if self.image.ndim == 2:
            return WALL_GRAY
        return WALL_RGB


def _gray(rgb: tuple[int, int, int]) -> float:
    r, g, b = rgb
    return 0.299 * r + 0.587 * g + 0.114 * b


WALL_GRAY = int(round(_gray(WALL_RGB)))
"""The walls as the grayscale camera sees them."""


def _fixed(tex_pts: np.ndarray) -> np.ndarray:
    return np.round(tex_pts * _SCALE).astype(np.int32).reshape(-1, 1, 2)


def _dashes(track: Track, dash: float) -> list[np.ndarray]:
    """Centre-line pieces ``dash`` metres long with ``dash`` gaps, as world polylines."""
    pieces = []
    s = 0.0
    end = track.length - (dash if track.closed else 0.0)
    while s < end:
        ss = np.linspace(s, min(s + dash, track.length), 6)
        pieces.append(np.array([track.point_at(v) for v in ss]))
        s += 2 * dash
    return pieces


def render_ground(
    track: Track,
    *,
    resolution: float = 0.005,
    rgb: bool = False,
    margin: float = MARGIN_M,
    colours: dict[str, tuple[int, int, int]] | None = None,
) -> GroundTexture:
    """Paint the track seen from above: floor, road, border lines, centre dashes, start line.

    ``resolution`` is metres per pixel (5 mm by default: fine enough for a 160×120 camera
    looking at the ground from 12 cm up). Returns an RGB or grayscale :class:`GroundTexture`.
    ``colours`` replaces some of the RGB colours (keys ``floor``, ``road``, ``border``,
    ``centre``, ``start``; :mod:`racing.conditions` paints class codes with it).
    """
    paint_colours = {"floor": FLOOR_RGB, "road": ROAD_RGB, "border": BORDER_RGB,
                     "centre": CENTRE_RGB, "start": START_RGB, **(colours or {})}  # fmt: skip
    floor_rgb, road_rgb, border_rgb, centre_rgb, start_rgb = (
        paint_colours[k] for k in ("floor", "road", "border", "centre", "start")
    )
    xmin, ymin, xmax, ymax = track.bounds()
    x0, y1 = xmin - margin, ymax + margin
    width = int(np.ceil((xmax - xmin + 2 * margin) / resolution))
    height = int(np.ceil((ymax - ymin + 2 * margin) / resolution))
    tex = GroundTexture(np.empty(0), x0, y1, resolution)
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = floor_rgb

    outer = _fixed(tex.to_pixels(track.outer))
    inner = _fixed(tex.to_pixels(track.inner))
    line_px = max(1, int(round(BORDER_LINE_M / resolution)))
    if track.closed:
        cv2.fillPoly(image, [outer], border_rgb, cv2.LINE_AA, _SHIFT)
        cv2.fillPoly(image, [inner], floor_rgb, cv2.LINE_AA, _SHIFT)
        # Road = the outer polygon shrunk by the line width, minus the inner one grown by it.
        road = np.zeros((height, width), dtype=np.uint8)
        cv2.fillPoly(road, [outer], 255, cv2.LINE_AA, _SHIFT)
        hole = np.zeros_like(road)
        cv2.fillPoly(hole, [inner], 255, cv2.LINE_AA, _SHIFT)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * line_px + 1, 2 * line_px + 1))
        road = cv2.erode(road, kernel)
        hole = cv2.dilate(hole, kernel)
        mask = (road.astype(np.int16) - hole.astype(np.int16)).clip(0, 255).astype(np.float32)
        paint = (mask / 255.0)[..., None]
        image[:] = (image * (1 - paint) + np.array(road_rgb, np.float32) * paint).astype(np.uint8)
    else:
        strip = _fixed(tex.to_pixels(np.vstack([track.inner, track.outer[::-1]])))
        cv2.fillPoly(image, [strip], road_rgb, cv2.LINE_AA, _SHIFT)
        for border in (inner, outer):
            cv2.polylines(image, [border], False, border_rgb, 2 * line_px, cv2.LINE_AA, _SHIFT)

    centre_px = max(1, int(round(CENTRE_LINE_M / resolution)))
    dashes = [_fixed(tex.to_pixels(p)) for p in _dashes(track, CENTRE_DASH_M)]
    cv2.polylines(image, dashes, False, centre_rgb, centre_px, cv2.LINE_AA, _SHIFT)

    # Start line: across the road at waypoint 0.
    h = track.heading_at(0.0)
    half = float(track.widths[0]) / 2
    cx, cy = track.centre[0]
    nx, ny = -np.sin(h), np.cos(h)
    ends = np.array([[cx - nx * half, cy - ny * half], [cx + nx * half, cy + ny * half]])
    cv2.polylines(
        image, [_fixed(tex.to_pixels(ends))], False, start_rgb, line_px, cv2.LINE_AA, _SHIFT
    )

    if not rgb:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return GroundTexture(image, x0, y1, resolution)
