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
MAX_DRAW_DISTANCE_M = 15.0
"""Objects farther than this from the camera are a pixel or two wide and are not drawn, metres."""
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


def objects_colours(objects: Sequence[RaceObject]) -> list[RGB]:
    return [BOT_RGB if o.kind == KIND_BOT else BOX_RGB for o in objects]


@dataclass(frozen=True)
class BoxSet:
    """Boxes ready to draw from any camera: world ``corners`` ``(N, 8, 3)``, their centres and
    bounding-sphere radii (metres), face centres and outward normals ``(N, 5, 3)``, colours."""

    corners: np.ndarray
    centres: list[tuple[float, float, float]]
    radii: list[float]
    face_centres: np.ndarray
    normals: np.ndarray
    colours: list[RGB]

    @classmethod
    def build(cls, corners: np.ndarray, colours: Sequence[RGB]) -> BoxSet:
        centre = corners.mean(axis=1)
        face_centres = corners[:, _FACE_CORNERS].mean(axis=2)
        radii = np.linalg.norm(corners[:, 0] - corners[:, 7], axis=1) / 2
        return cls(
            corners=corners,
            centres=[tuple(c) for c in centre.tolist()],
            radii=radii.tolist(),
            face_centres=face_centres,
            normals=face_centres - centre[:, None],
            colours=list(colours),
        )

    @classmethod
    def of(cls, objects: Sequence[RaceObject]) -> BoxSet:
        return cls.build(objects_corners(objects), objects_colours(objects))


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
    img: np.ndarray, k: np.ndarray, position: np.ndarray, rotation: np.ndarray, boxes: BoxSet
) -> None:
    """Paint ``boxes`` into ``img`` (grayscale ``(H, W)`` or RGB) as seen by a camera at
    ``position`` with world→camera ``rotation`` (OpenCV axes) and intrinsics ``k``.

    Boxes wholly behind the camera, beside its field of view or beyond
    :data:`MAX_DRAW_DISTANCE_M` are culled by their bounding spheres in plain Python, so a
    frame with no object in view costs a few microseconds more than the ground alone.
    """
    w = img.shape[1]
    px, py, pz = position.tolist()
    (rx, ry, rz), _, (fx, fy, fz) = rotation.tolist()
    half_fov = math.atan((w / 2) / k[0, 0])
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
    if not visible:
        return
    scale = float(1 << SUBPIXEL_BITS)
    focal = np.array([k[0, 0], k[1, 1]])
    principal = np.array([k[0, 2], k[1, 2]])
    order = [i for _, i in sorted(visible, reverse=True)]  # farthest first
    cams = (boxes.corners[order] - position) @ rotation.T
    facing = (
        np.einsum("nfk,nfk->nf", boxes.normals[order], position - boxes.face_centres[order]) > 0
    )
    ahead = (cams[..., 2].min(axis=1) > NEAR_M).tolist()
    # Depths are at least NEAR_M and distances at most MAX_DRAW_DISTANCE_M, so pixel
    # coordinates stay within a few 10⁵ and fit int32 at 1/16 pixel.
    fixed = None
    if any(ahead):
        front = cams[ahead]
        uv = front[..., :2] / front[..., 2:3] * focal + principal
        rounded = np.round(uv * scale).astype(np.int32)
        fixed = np.ascontiguousarray(rounded[:, _FACE_CORNERS])  # (m, 5, 4, 2) for cv2
    row = 0
    for n, i in enumerate(order):
        rgb = boxes.colours[i]
        pts_all = None
        if ahead[n]:
            pts_all = fixed[row]
            row += 1
        for f, looks in enumerate(facing[n].tolist()):
            if not looks:
                continue
            if pts_all is not None:
                pts = pts_all[f]
            else:
                poly = _clip_near(cams[n, _FACE_CORNERS[f]])
                if len(poly) < 3:
                    continue
                uv_f = poly[:, :2] / poly[:, 2:3] * focal + principal
                pts = np.round(uv_f * scale).astype(np.int32)
            shade = _FACE_SHADES[f]
            if img.ndim == 2:
                gray = shade * (0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2])
                cv2.fillConvexPoly(img, pts, int(gray), cv2.LINE_AA, SUBPIXEL_BITS)
            else:
                colour = tuple(int(c * shade) for c in rgb)
                cv2.fillConvexPoly(img, pts, colour, cv2.LINE_AA, SUBPIXEL_BITS)
