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
from dataclasses import dataclass

import cv2
import numpy as np

from racing.objects import KIND_BOT, RaceObject

NEAR_M = 0.02
"""Near clipping plane, metres in front of the lens."""
MAX_DRAW_DISTANCE_M = 10.0
"""Objects farther than this from the camera are not drawn, metres: the front camera shows a box
there under 2 pixels wide and a pixel high."""
SUBPIXEL_BITS = 4
"""Fixed-point fraction bits for cv2's polygon filling (1/16 pixel)."""

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

_FACE_CORNERS = np.array([idx for idx, _ in _FACES])
_FACE_INDICES = tuple(idx for idx, _ in _FACES)
_FACE_SHADES = tuple(shade for _, shade in _FACES)

RGB = tuple[int, int, int]


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


def objects_corners(objects: Sequence[RaceObject]) -> np.ndarray:
    """World corners ``(N, 8, 3)`` of every object's box, in one go."""
    if not objects:
        return np.zeros((0, 8, 3))
    data = np.array([(o.x, o.y, o.heading, o.length, o.width, o.height) for o in objects])
    local = _CORNERS[None] * data[:, None, 3:6]
    c, s = np.cos(data[:, 2:3]), np.sin(data[:, 2:3])
    world = np.empty_like(local)
    world[..., 0] = data[:, 0:1] + c * local[..., 0] - s * local[..., 1]
    world[..., 1] = data[:, 1:2] + s * local[..., 0] + c * local[..., 1]
    world[..., 2] = local[..., 2]
    return world


def object_colour(obj: RaceObject) -> RGB:
    """A racer's own colour, else the colour of a bot or of a box."""
    if obj.colour is not None:
        return obj.colour
    return BOT_RGB if obj.kind == KIND_BOT else BOX_RGB


def objects_colours(objects: Sequence[RaceObject]) -> list[RGB]:
    return [object_colour(o) for o in objects]


Point3 = tuple[float, float, float]


@dataclass(frozen=True)
class BoxSet:
    """Boxes ready to draw from any camera, as plain floats (metres): each box's eight
    ``corners``, its centre and bounding-sphere radius, its faces' centres and outward normals,
    and its colour."""

    corners: list[list[Point3]]
    centres: list[Point3]
    radii: list[float]
    face_centres: list[list[Point3]]
    normals: list[list[Point3]]
    colours: list[RGB]

    @classmethod
    def build(cls, corners: np.ndarray, colours: Sequence[RGB]) -> BoxSet:
        """From world corners ``(N, 8, 3)`` and one RGB colour per box."""
        centre = corners.mean(axis=1)
        face_centres = corners[:, _FACE_CORNERS].mean(axis=2)
        radii = np.linalg.norm(corners[:, 0] - corners[:, 7], axis=1) / 2
        return cls(
            corners=[[tuple(c) for c in box] for box in corners.tolist()],
            centres=[tuple(c) for c in centre.tolist()],
            radii=radii.tolist(),
            face_centres=[[tuple(c) for c in box] for box in face_centres.tolist()],
            normals=[[tuple(n) for n in box] for box in (face_centres - centre[:, None]).tolist()],
            colours=list(colours),
        )

    @classmethod
    def of(cls, objects: Sequence[RaceObject]) -> BoxSet:
        return cls.build(objects_corners(objects), objects_colours(objects))


def _clip_near(points: list[Point3]) -> list[Point3]:
    """The part of a convex polygon (camera coordinates) in front of the near plane."""
    out: list[Point3] = []
    n = len(points)
    for i in range(n):
        a, b = points[i], points[(i + 1) % n]
        a_in, b_in = a[2] >= NEAR_M, b[2] >= NEAR_M
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (NEAR_M - a[2]) / (b[2] - a[2])
            out.append((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), NEAR_M))
    return out


def draw_boxes(
    img: np.ndarray, k: np.ndarray, position: np.ndarray, rotation: np.ndarray, boxes: BoxSet
) -> None:
    """Paint ``boxes`` into ``img`` (grayscale ``(H, W)`` or RGB) as seen by a camera at
    ``position`` with world→camera ``rotation`` (OpenCV axes) and intrinsics ``k``.

    Boxes wholly behind the camera, beside its field of view or beyond
    :data:`MAX_DRAW_DISTANCE_M` are culled by their bounding spheres. The few boxes left are
    projected in plain floats (cheaper than NumPy calls for eight points), so a frame with no
    object in view costs a few microseconds more than the ground alone.
    """
    w = img.shape[1]
    px, py, pz = position.tolist()
    (rx, ry, rz), (dx_, dy_, dz_), (fx, fy, fz) = rotation.tolist()
    fu, cu, fv, cv = float(k[0, 0]), float(k[0, 2]), float(k[1, 1]), float(k[1, 2])
    half_fov = math.atan((w / 2) / fu)
    cos_h, sin_h = math.cos(half_fov), math.sin(half_fov)
    visible = []
    for i, (cx, cy, cz) in enumerate(boxes.centres):
        dx, dy, dz = cx - px, cy - py, cz - pz
        distance = math.sqrt(dx * dx + dy * dy + dz * dz)
        r = boxes.radii[i]
        depth = dx * fx + dy * fy + dz * fz
        lateral = dx * rx + dy * ry + dz * rz
        if distance > MAX_DRAW_DISTANCE_M or depth < NEAR_M - r:
            continue
        if abs(lateral) * cos_h - depth * sin_h > r:
            continue  # wholly beside the field of view
        visible.append((distance, i))
    scale = float(1 << SUBPIXEL_BITS)
    for _, i in sorted(visible, reverse=True):  # farthest first
        cam = []
        for x, y, z in boxes.corners[i]:
            x, y, z = x - px, y - py, z - pz
            cam.append(
                (x * rx + y * ry + z * rz, x * dx_ + y * dy_ + z * dz_, x * fx + y * fy + z * fz)
            )
        ahead = min(c[2] for c in cam) >= NEAR_M
        rgb = boxes.colours[i]
        for f, ((nx, ny, nz), (ox, oy, oz)) in enumerate(
            zip(boxes.normals[i], boxes.face_centres[i], strict=True)
        ):
            if nx * (px - ox) + ny * (py - oy) + nz * (pz - oz) <= 0.0:
                continue  # the face looks away from the camera
            poly = [cam[j] for j in _FACE_INDICES[f]]
            if not ahead:
                poly = _clip_near(poly)
                if len(poly) < 3:
                    continue
            # Depths are at least NEAR_M and distances at most MAX_DRAW_DISTANCE_M, so the
            # pixel coordinates stay within a few 10⁵ and fit int32 at 1/16 pixel.
            pts = np.array(
                [
                    (round((fu * a / c + cu) * scale), round((fv * b / c + cv) * scale))
                    for a, b, c in poly
                ],
                dtype=np.int32,
            )
            shade = _FACE_SHADES[f]
            if img.ndim == 2:
                gray = shade * (0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2])
                cv2.fillConvexPoly(img, pts, int(gray), cv2.LINE_AA, SUBPIXEL_BITS)
            else:
                colour = tuple(int(c * shade) for c in rgb)
                cv2.fillConvexPoly(img, pts, colour, cv2.LINE_AA, SUBPIXEL_BITS)
