"""Pictures for people: the RGB chase view and the top-down view used for video.

Both reuse the fast ground projection of :mod:`racing.sensors` on an RGB ground texture and
draw the car, the boxes and the bot cars as shaded boxes on top (nearer over farther).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from racing.car import CHASSIS_CENTRE_X, Pose
from racing.drawing import (
    BoxSet,
    box_corners,
    draw_boxes,
    object_colour,
    objects_colours,
    objects_corners,
)
from racing.objects import RaceObject
from racing.sensors import CameraMount, PinholeCamera, camera_frame
from racing.texture import GroundTexture

CHASE_MOUNT = CameraMount(
    forward=-0.75, height=0.5, pitch_deg=27.0, hfov_deg=80.0, width=320, height_px=240
)
"""A camera 0.75 m behind and 0.5 m above the car's origin, looking down the track."""

CAR_LENGTH_M = 0.36
CAR_WIDTH_M = 0.19
CAR_HEIGHT_M = 0.11
CAR_RGB = (214, 48, 49)


def car_box(pose: Pose) -> np.ndarray:
    cx = pose.x + (CHASSIS_CENTRE_X + 0.02) * math.cos(pose.yaw)
    cy = pose.y + (CHASSIS_CENTRE_X + 0.02) * math.sin(pose.yaw)
    return box_corners(cx, cy, pose.yaw, CAR_LENGTH_M, CAR_WIDTH_M, CAR_HEIGHT_M)


class ChaseView:
    """A third-person RGB view from behind the car, 320×240."""

    def __init__(self, ground_rgb: GroundTexture) -> None:
        self.camera = PinholeCamera(ground_rgb, CHASE_MOUNT)

    def render(self, pose: Pose, objects: Sequence[RaceObject] = ()) -> np.ndarray:
        """The view behind the car at ``pose``, ``(240, 320, 3)`` RGB, objects included."""
        img = self.camera.render(pose)
        pos, rot = camera_frame(pose, self.camera.mount)
        corners = np.concatenate([objects_corners(objects), car_box(pose)[None]])
        boxes = BoxSet.build(corners, [*objects_colours(objects), CAR_RGB])
        draw_boxes(img, self.camera.K, pos, rot, boxes)
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

    def render(self, pose: Pose, objects: Sequence[RaceObject] = ()) -> np.ndarray:
        """The whole track from above with the objects and the car on it, RGB."""
        img = self.base.copy()
        for obj in objects:
            self.draw_object(img, obj)
        self.draw_car(img, pose, CAR_RGB)
        return img

    def draw_object(self, img: np.ndarray, obj: RaceObject) -> None:
        """A box, bot or racer's footprint in its colour."""
        self._draw_footprint(
            img, obj.x, obj.y, obj.heading, obj.length, obj.width, object_colour(obj)
        )

    def draw_car(self, img: np.ndarray, pose: Pose, rgb: tuple[int, int, int]) -> None:
        """A car at ``pose`` drawn 1.6 times its size (so that it shows on a whole track)."""
        cx = pose.x + (CHASSIS_CENTRE_X + 0.02) * math.cos(pose.yaw)
        cy = pose.y + (CHASSIS_CENTRE_X + 0.02) * math.sin(pose.yaw)
        self._draw_footprint(img, cx, cy, pose.yaw, CAR_LENGTH_M * 1.6, CAR_WIDTH_M * 1.6, rgb)

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
