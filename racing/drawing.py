"""Solid boxes drawn into a camera image: the boxes and bot cars on the track, and the car itself
in the chase view.

A box is eight world corners. Its faces that look towards the camera are clipped at the near
plane (so a box partly behind the camera shows only its visible part, and one wholly behind is
not drawn), projected and filled, shaded per face. Boxes are painted farthest first, so nearer
objects cover farther ones; the ground (already in the image) is covered by every object.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from racing.objects import KIND_BOT, RaceObject

NEAR_M = 0.02
"""Near clipping plane, metres in front of the lens."""
MAX_DRAW_DISTANCE_M = 15.0
"""Objects farther than this from the camera are a pixel or two wide and are not drawn, metres."""
SUBPIXEL_BITS = 4
"""Fixed-point fraction bits for cv2's polygon filling (1/16 pixel)."""
PIXEL_LIMIT = 1e5
"""Projected coordinates are clamped to ± this many pixels, far outside any image."""

BOX_RGB = (201, 160, 99)
BOT_RGB = (60, 110, 220)

# Unit cube corners (index = 4·x + 2·y + z over {-½, ½}² × {0, 1}) and its faces, bottom omitted.
_CORNERS = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (0.0, 1.0)], dtype=np.float64
)
_FACES = (
    ((1, 3, 7, 5), 1.0),  # top
    ((0, 1, 3, 2), 0.72),  # back
    ((4, 5, 7, 6), 0.8),  # front
    ((0, 1, 5, 4), 0.62),  # right
    ((2, 3, 7, 6), 0.66),  # left
)

Box = tuple[np.ndarray, tuple[int, int, int]]
"""Eight world corners ``(8, 3)`` in metres and an RGB colour."""


def box_corners(
    cx: float, cy: float, yaw: float, length: float, width: float, height: float
) -> np.ndarray:
    """World corners ``(8, 3)`` of a box standing on the floor, centred at ``(cx, cy)``."""
    c, s = math.cos(yaw), math.sin(yaw)
    local = _CORNERS * np.array([length, width, height])
    world = np.empty_like(local)
    world[:, 0] = cx + c * local[:, 0] - s * local[:, 1]
    world[:, 1] = cy + s * local[:, 0] + c * local[:, 1]
    world[:, 2] = local[:, 2]
    return world


def object_box(obj: RaceObject) -> Box:
    """A race object as a drawable box in its colour."""
    rgb = BOT_RGB if obj.kind == KIND_BOT else BOX_RGB
    return box_corners(obj.x, obj.y, obj.heading, obj.length, obj.width, obj.height), rgb


def _clip_near(points: np.ndarray) -> np.ndarray:
    """The part of a convex polygon (camera coordinates, ``(N, 3)``) in front of the near plane."""
    inside = points[:, 2] >= NEAR_M
    if inside.all():
        return points
    out = []
    n = len(points)
    for i in range(n):
        a, b = points[i], points[(i + 1) % n]
        if inside[i]:
            out.append(a)
        if inside[i] != inside[(i + 1) % n]:
            t = (NEAR_M - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out)


def draw_boxes(
    img: np.ndarray,
    k: np.ndarray,
    position: np.ndarray,
    rotation: np.ndarray,
    boxes: Sequence[Box],
) -> None:
    """Paint ``boxes`` into ``img`` (grayscale ``(H, W)`` or RGB) as seen by a camera at
    ``position`` with world→camera ``rotation`` (OpenCV axes) and intrinsics ``k``."""
    h, w = img.shape[:2]
    visible = []
    for corners, rgb in boxes:
        cam = (corners - position) @ rotation.T
        z = cam[:, 2]
        if z.max() < NEAR_M:
            continue
        centre = corners.mean(axis=0)
        distance = float(np.linalg.norm(centre - position))
        if distance > MAX_DRAW_DISTANCE_M:
            continue
        if z.min() > NEAR_M:
            u = k[0, 0] * cam[:, 0] / z + k[0, 2]
            v = k[1, 1] * cam[:, 1] / z + k[1, 2]
            if u.max() < 0 or u.min() >= w or v.max() < 0 or v.min() >= h:
                continue
        visible.append((distance, corners, centre, cam, rgb))
    visible.sort(key=lambda item: -item[0])
    scale = float(1 << SUBPIXEL_BITS)
    for _, corners, centre, cam, rgb in visible:
        for idx, shade in _FACES:
            ids = list(idx)
            face_centre = corners[ids].mean(axis=0)
            if np.dot(face_centre - centre, position - face_centre) <= 0:
                continue  # the face looks away from the camera
            poly = _clip_near(cam[ids])
            if len(poly) < 3:
                continue
            uv = (poly[:, :2] / poly[:, 2:3]) * (k[0, 0], k[1, 1]) + (k[0, 2], k[1, 2])
            pts = np.round(np.clip(uv, -PIXEL_LIMIT, PIXEL_LIMIT) * scale).astype(np.int32)
            colour = tuple(int(c * shade) for c in rgb)
            if img.ndim == 2:
                gray = 0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2]
                cv2.fillConvexPoly(img, pts, int(gray), cv2.LINE_AA, SUBPIXEL_BITS)
            else:
                cv2.fillConvexPoly(img, pts, colour, cv2.LINE_AA, SUBPIXEL_BITS)
