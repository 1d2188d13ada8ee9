"""Pictures for people: the RGB chase view and the top-down view used for video.

Both reuse the fast ground projection of :mod:`racing.sensors` on an RGB ground texture and
draw the car (and later objects) as shaded boxes on top.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from racing.car import CHASSIS_CENTRE_X, Pose
from racing.params import RaceObject
from racing.sensors import CameraMount, PinholeCamera
from racing.texture import GroundTexture

CHASE_MOUNT = CameraMount(
    forward=-0.75, height=0.5, pitch_deg=27.0, hfov_deg=80.0, width=320, height_px=240
)
"""A camera 0.75 m behind and 0.5 m above the car's origin, looking down the track."""

CAR_LENGTH_M = 0.36
CAR_WIDTH_M = 0.19
CAR_HEIGHT_M = 0.11
CAR_RGB = (214, 48, 49)
OBJECT_RGB = {"box": (201, 160, 99), "bot": (60, 110, 220)}

# Unit cube corners and faces (indices) with an outward normal each.
_CORNERS = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (0.0, 1.0)], dtype=np.float64
)
_FACES = (
    ((1, 3, 7, 5), (0, 0, 1)),  # top
    ((0, 1, 3, 2), (-1, 0, 0)),  # back
    ((4, 5, 7, 6), (1, 0, 0)),  # front
    ((0, 1, 5, 4), (0, -1, 0)),  # right
    ((2, 3, 7, 6), (0, 1, 0)),  # left
)
_SHADE = (1.0, 0.72, 0.8, 0.62, 0.66)


def box_corners(cx: float, cy: float, yaw: float, length: float, width: float, height: float):
    c, s = math.cos(yaw), math.sin(yaw)
    local = _CORNERS * np.array([length, width, height])
    world = np.empty_like(local)
    world[:, 0] = cx + c * local[:, 0] - s * local[:, 1]
    world[:, 1] = cy + s * local[:, 0] + c * local[:, 1]
    world[:, 2] = local[:, 2]
    return world


def draw_box(img: np.ndarray, cam: PinholeCamera, pose: Pose, corners: np.ndarray, rgb) -> None:
    """Draw a solid box seen by ``cam`` on a car at ``pose`` (faces away from it are skipped)."""
    pix, depth = cam.project(pose, corners)
    if np.all(depth <= 0.02):
        return
    eye = cam_position(cam, pose)
    yaw_vec = corners[4, :2] - corners[0, :2]
    yaw = math.atan2(yaw_vec[1], yaw_vec[0])
    c, s = math.cos(yaw), math.sin(yaw)
    faces = []
    for (idx, normal), shade in zip(_FACES, _SHADE, strict=True):
        nx, ny, nz = normal
        n_world = np.array([c * nx - s * ny, s * nx + c * ny, nz])
        face_centre = corners[list(idx)].mean(axis=0)
        if np.dot(n_world, eye - face_centre) <= 0 or np.any(depth[list(idx)] <= 0.02):
            continue
        faces.append((float(np.linalg.norm(face_centre - eye)), idx, shade))
    for _, idx, shade in sorted(faces, reverse=True):
        pts = np.round(pix[list(idx)] * 16).astype(np.int32)
        colour = tuple(int(v * shade) for v in rgb)
        if img.ndim == 2:
            colour = int(0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2])
        cv2.fillConvexPoly(img, pts, colour, cv2.LINE_AA, 4)


def cam_position(cam: PinholeCamera, pose: Pose) -> np.ndarray:
    m = cam.mount
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return np.array(
        [pose.x + c * m.forward - s * m.left, pose.y + s * m.forward + c * m.left, m.height]
    )


def car_box(pose: Pose) -> np.ndarray:
    cx = pose.x + (CHASSIS_CENTRE_X + 0.02) * math.cos(pose.yaw)
    cy = pose.y + (CHASSIS_CENTRE_X + 0.02) * math.sin(pose.yaw)
    return box_corners(cx, cy, pose.yaw, CAR_LENGTH_M, CAR_WIDTH_M, CAR_HEIGHT_M)


class ChaseView:
    """A third-person RGB view from behind the car, 320×240."""

    def __init__(self, ground_rgb: GroundTexture) -> None:
        self.camera = PinholeCamera(ground_rgb, CHASE_MOUNT)

    def render(self, pose: Pose, objects: tuple[RaceObject, ...] = ()) -> np.ndarray:
        img = self.camera.render(pose)
        for obj in objects:
            corners = box_corners(obj.x, obj.y, obj.heading, obj.length, obj.width, obj.height)
            draw_box(img, self.camera, pose, corners, OBJECT_RGB.get(obj.kind, OBJECT_RGB["box"]))
        draw_box(img, self.camera, pose, car_box(pose), CAR_RGB)
        return img


class TopDownView:
    """The whole track from above, ``width_px`` wide, with the car drawn on it."""

    def __init__(self, ground_rgb: GroundTexture, width_px: int = 480) -> None:
        h, w = ground_rgb.image.shape[:2]
        self.scale = width_px / w
        self.base = cv2.resize(
            ground_rgb.image,
            (width_px, max(1, int(round(h * self.scale)))),
            interpolation=cv2.INTER_AREA,
        )
        self.ground = ground_rgb

    def render(self, pose: Pose, objects: tuple[RaceObject, ...] = ()) -> np.ndarray:
        img = self.base.copy()
        for obj in objects:
            self._draw_footprint(
                img,
                obj.x,
                obj.y,
                obj.heading,
                obj.length,
                obj.width,
                OBJECT_RGB.get(obj.kind, OBJECT_RGB["box"]),
            )
        cx = pose.x + (CHASSIS_CENTRE_X + 0.02) * math.cos(pose.yaw)
        cy = pose.y + (CHASSIS_CENTRE_X + 0.02) * math.sin(pose.yaw)
        self._draw_footprint(img, cx, cy, pose.yaw, CAR_LENGTH_M * 1.6, CAR_WIDTH_M * 1.6, CAR_RGB)
        return img

    def _draw_footprint(self, img, x, y, yaw, length, width, rgb) -> None:
        c, s = math.cos(yaw), math.sin(yaw)
        local = np.array([[0.5, 0.5], [0.5, -0.5], [-0.5, -0.5], [-0.5, 0.5], [0.75, 0.0]])
        local = local * np.array([length, width])
        world = np.stack(
            [x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]], 1
        )
        pix = self.ground.to_pixels(world) * self.scale
        pts = np.round(pix * 16).astype(np.int32)
        cv2.fillConvexPoly(img, pts[:4], rgb, cv2.LINE_AA, 4)
        cv2.fillConvexPoly(img, pts[[0, 4, 1]], (250, 250, 250), cv2.LINE_AA, 4)
