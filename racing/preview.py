"""Small top-down PNG pictures of a track for the console's track picker.

The picture is the same ground texture the cameras see (:func:`racing.texture.render_ground`),
rendered a little finer than needed and shrunk with area averaging so thin lines stay smooth,
then cropped to the track with a small margin. On top of it: a chequered start line across the
road at waypoint 0 and an arrow pointing the driving direction.

A race's preview (:func:`render_race_preview_png`) adds the objects of an episode's start, as
the simulator places them: boxes at their fixed (or one random draw of their) places, bot cars
at their starting places, each drawn to scale in the colours the cameras see them.

:func:`render_conditions_preview_png` shows what the car's camera sees under training
conditions (:mod:`racing.conditions`): the model's own 160×120 grayscale frame, enlarged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from racing.conditioned_camera import conditioned, pose_at
from racing.conditions import Conditions
from racing.drawing import objects_colours
from racing.objects import BotFleet, Lanes, RaceObject, place_boxes
from racing.race import RaceConfig
from racing.sensors import CameraSensor, ground_for
from racing.texture import render_ground
from racing.track import Track

MARGIN_M = 0.25
"""Floor shown around the track's bounding box, metres."""
SUPERSAMPLE = 2
"""The texture is rendered this many times finer than the final picture, then shrunk."""
FINEST_RESOLUTION_M = 0.004
"""Never render finer than this (metres per pixel), however large the picture asked for."""
MAX_RENDER_PX = 2048
"""Never render the texture wider than this before shrinking (keeps big previews fast)."""
MIN_WIDTH_PX = 32
MAX_WIDTH_PX = 4096

ARROW_RGB = (228, 48, 40)
CHEQUER_DARK_RGB = (20, 20, 20)
CHEQUER_LIGHT_RGB = (245, 245, 245)
CHEQUER_SQUARES = 8
"""Squares across the road in each of the start line's two rows."""
ARROW_LENGTH_M = 0.7
"""Nominal arrow length along the centre line, metres (shorter on tiny tracks)."""

OUTLINE_RGB = (25, 25, 25)
"""The dark edge round each object, so that a box stands out on the road."""

_SHIFT = 4  # fixed-point bits for sub-pixel drawing
_SCALE = 1 << _SHIFT


def render_preview_png(track: Track, width_px: int = 480) -> bytes:
    """A top-down PNG of ``track``, ``width_px`` pixels wide, in the driving direction.

    The height follows the track's aspect ratio. The start line is chequered and an arrow just
    past it shows which way the car drives. The output depends only on the track and
    ``width_px`` (same bytes every call). Raises ``ValueError`` for a width outside
    ``MIN_WIDTH_PX..MAX_WIDTH_PX``.
    """
    return _png(render_preview(track, width_px))


def race_objects(track: Track, config: RaceConfig, seed: int = 0) -> tuple[RaceObject, ...]:
    """The boxes or bot cars of an episode's start on ``track`` (in its driving direction), as
    the simulator places them; random placements are the draw of ``seed``. Raises
    ``ValueError`` when they do not fit on the track."""
    rng = np.random.default_rng(seed)
    if config.has_boxes:
        return place_boxes(track, Lanes(track), config, rng)
    if config.has_bots:
        return BotFleet(track, Lanes(track), config, rng).objects
    return ()


def render_race_preview_png(
    track: Track, config: RaceConfig, width_px: int = 480, seed: int = 0
) -> bytes:
    """:func:`render_preview_png` with the race's objects (:func:`race_objects`) on it."""
    return _png(render_preview(track, width_px, objects=race_objects(track, config, seed)))


def _png(image: np.ndarray) -> bytes:
    ok, buffer = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover - cv2 only fails on empty or odd images
        raise RuntimeError("PNG encoding failed")
    return buffer.tobytes()


def render_preview(
    track: Track, width_px: int = 480, *, objects: tuple[RaceObject, ...] = ()
) -> np.ndarray:
    """The preview as an ``(H, width_px, 3)`` uint8 RGB array (see :func:`render_preview_png`),
    with ``objects`` drawn on it from above."""
    if not MIN_WIDTH_PX <= int(width_px) <= MAX_WIDTH_PX:
        raise ValueError(f"width_px must be {MIN_WIDTH_PX}..{MAX_WIDTH_PX}, not {width_px}")
    width_px = int(width_px)
    xmin, ymin, xmax, ymax = track.bounds()
    span_x = xmax - xmin + 2 * MARGIN_M
    span_y = ymax - ymin + 2 * MARGIN_M
    final_res = span_x / width_px
    resolution = max(final_res / SUPERSAMPLE, FINEST_RESOLUTION_M, span_x / MAX_RENDER_PX)
    texture = render_ground(track, resolution=resolution, rgb=True, margin=MARGIN_M)
    height_px = max(1, int(round(span_y / final_res)))
    image = cv2.resize(texture.image, (width_px, height_px), interpolation=cv2.INTER_AREA)
    scale = (width_px / texture.image.shape[1], height_px / texture.image.shape[0])

    def to_px(points: np.ndarray) -> np.ndarray:
        px = texture.to_pixels(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        px = (px + 0.5) * np.asarray(scale) - 0.5
        return np.round(px * _SCALE).astype(np.int32)

    _draw_start_line(image, track, to_px)
    _draw_arrow(image, track, to_px, px_per_m=width_px / span_x)
    _draw_objects(image, objects, to_px, px_per_m=width_px / span_x)
    return image


def _draw_objects(image: np.ndarray, objects, to_px, *, px_per_m: float) -> None:
    """Each object's footprint, to scale, filled with its camera colour and outlined."""
    edge = max(1, int(round(0.015 * px_per_m)))
    for obj, colour in zip(objects, objects_colours(objects), strict=True):
        c, s = math.cos(obj.heading), math.sin(obj.heading)
        hl, hw = obj.length / 2, obj.width / 2
        corners = np.array(
            [(obj.x + a * c - b * s, obj.y + a * s + b * c)
             for a, b in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]
        )  # fmt: skip
        pts = to_px(corners)
        cv2.fillConvexPoly(image, pts, colour, cv2.LINE_AA, _SHIFT)
        cv2.polylines(image, [pts], True, OUTLINE_RGB, edge, cv2.LINE_AA, _SHIFT)


def _draw_start_line(image: np.ndarray, track: Track, to_px) -> None:
    """Two rows of black and white squares across the road at waypoint 0."""
    heading = track.heading_at(0.0)
    along = np.array([math.cos(heading), math.sin(heading)])
    across = np.array([-math.sin(heading), math.cos(heading)])
    half = float(track.widths[0]) / 2
    square = 2 * half / CHEQUER_SQUARES
    centre = np.asarray(track.centre[0], dtype=np.float64)
    for row in range(2):
        for col in range(CHEQUER_SQUARES):
            a0, a1 = (row - 1) * square, row * square
            c0, c1 = -half + col * square, -half + (col + 1) * square
            corners = np.array(
                [
                    centre + a * along + c * across
                    for a, c in ((a0, c0), (a1, c0), (a1, c1), (a0, c1))
                ]
            )
            colour = CHEQUER_DARK_RGB if (row + col) % 2 else CHEQUER_LIGHT_RGB
            cv2.fillConvexPoly(image, to_px(corners), colour, cv2.LINE_AA, _SHIFT)


def _draw_arrow(image: np.ndarray, track: Track, to_px, *, px_per_m: float) -> None:
    """An arrow along the centre line just past the start line, in the driving direction."""
    length = min(ARROW_LENGTH_M, 0.08 * track.length)
    # Begin one chequer square past the start line so the arrow does not hide it.
    start = float(track.widths[0]) / CHEQUER_SQUARES + 0.05
    if not track.closed:
        length = min(length, max(track.length - start, 0.0))
    if length <= 0:
        return
    tail = track.point_at(start)
    tip = track.point_at(start + length)
    p0, p1 = to_px(np.array([tail, tip]))
    thickness = max(2, int(round(0.05 * px_per_m)))
    arrow_px = float(np.hypot(*(p1 - p0))) / _SCALE
    tip_fraction = min(0.5, max(0.25, 8.0 / max(arrow_px, 1.0)))
    cv2.arrowedLine(
        image,
        tuple(int(v) for v in p0),
        tuple(int(v) for v in p1),
        ARROW_RGB,
        thickness,
        cv2.LINE_AA,
        _SHIFT,
        tip_fraction,
    )


CONDITIONS_PREVIEW_SCALE = 2
"""The camera's 160×120 frame is shown this many times larger (nearest neighbour: the pixels
the model gets, each a square)."""
CONDITIONS_PREVIEW_SEED = 0
"""The generator of a preview's per-episode draws (where glare falls, the noise): fixed, so a
preview is the same picture every time."""


def render_conditions_preview_png(
    track: Track,
    conditions: Sequence[Conditions],
    *,
    at: float = 0.0,
    scale: int = CONDITIONS_PREVIEW_SCALE,
) -> list[bytes]:
    """For each of ``conditions``, a grayscale PNG of what the front camera gives the model
    (160×120, shown ``scale`` times larger) from a car on the centre line at fraction ``at``
    (0-1) of the lap of ``track`` (in its driving direction), facing along it. Clean
    conditions give the simulator's own frame. The same inputs give the same bytes."""
    if not 1 <= int(scale) <= 8:
        raise ValueError(f"scale must be 1-8, not {scale}")
    ground = ground_for(track, resolution=0.005, rgb=False)
    pose = pose_at(track, at)
    pictures = []
    for c in conditions:
        rng = np.random.default_rng(CONDITIONS_PREVIEW_SEED)
        camera = conditioned(CameraSensor(ground), track, c, rng)
        frame = camera.observe(pose)[..., 0]
        frame = cv2.resize(frame, None, fx=int(scale), fy=int(scale),
                           interpolation=cv2.INTER_NEAREST)  # fmt: skip
        ok, buffer = cv2.imencode(".png", frame)
        if not ok:  # pragma: no cover - cv2 only fails on empty or odd images
            raise RuntimeError("PNG encoding failed")
        pictures.append(buffer.tobytes())
    return pictures
