"""Pictures for people: the RGB chase view and the top-down view used for video.

Both reuse the fast ground projection of :mod:`racing.sensors` on an RGB ground texture and
draw the car, the boxes and the bot cars as shaded boxes on top (nearer over farther).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

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


TV_MOUNT = CameraMount(
    forward=-1.5, height=0.95, pitch_deg=27.0, hfov_deg=68.0, width=1280, height_px=720
)
"""The broadcast's TV camera: 1.5 m behind and 0.95 m above the followed car."""
TV_WIDE_MOUNT = CameraMount(
    forward=-2.4, height=1.9, pitch_deg=36.0, hfov_deg=72.0, width=1280, height_px=720
)
"""Its wide shot (an incident): further back and higher, to see what is round the car."""
SKY_TOP_RGB, SKY_BOTTOM_RGB = (20, 28, 46), (58, 72, 96)


class TVCamera:
    """The broadcast's camera: behind and above a car, RGB, every car and bot drawn.

    It follows the car's heading smoothly (a low-pass on the yaw, so a weaving car does not
    shake the picture) and jumps at a cut (:meth:`cut`). ``mounts`` maps a shot's camera
    (``chase``, ``wide``) to where the camera sits; the picture's size is the mounts'."""

    def __init__(self, ground_rgb: GroundTexture, *, width: int = 1280, height: int = 720,
                 smoothing: float = 0.3) -> None:  # fmt: skip
        self.cameras: dict[str, PinholeCamera] = {}
        for name, mount in (("chase", TV_MOUNT), ("wide", TV_WIDE_MOUNT)):
            camera = PinholeCamera(ground_rgb, replace(mount, width=width, height_px=height))
            camera._frame = _sky(height, width, camera.first_ground_row)
            self.cameras[name] = camera
        self.smoothing = smoothing
        self._yaw: float | None = None

    def cut(self) -> None:
        """The next frame frames its car afresh (no smoothing across a cut)."""
        self._yaw = None

    def render(self, pose: Pose, objects: Sequence[RaceObject] = (),
               camera: str = "chase") -> np.ndarray:  # fmt: skip
        """The picture behind the car at ``pose``, ``(height, width, 3)`` RGB."""
        if self._yaw is None:
            self._yaw = pose.yaw
        else:  # turn a share of the way toward the car's heading, the short way round
            turn = math.remainder(pose.yaw - self._yaw, math.tau)
            self._yaw += self.smoothing * turn
        cam = self.cameras.get(camera, self.cameras["chase"])
        return cam.render(Pose(pose.x, pose.y, self._yaw), objects)


def _sky(height: int, width: int, horizon: int) -> np.ndarray:
    """A dusk-blue gradient down to the horizon row (drawn once; a frame copies it)."""
    rows = max(1, min(height, horizon + 2))
    ramp = np.linspace(0.0, 1.0, rows)[:, None]
    top, bottom = np.array(SKY_TOP_RGB, float), np.array(SKY_BOTTOM_RGB, float)
    colours = (top * (1 - ramp) + bottom * ramp).astype(np.uint8)
    img = np.empty((height, width, 3), np.uint8)
    img[:] = SKY_BOTTOM_RGB
    img[:rows] = colours[:, None, :]
    return img


class TrackMap:
    """A small map of the whole track with each car and bot as a coloured dot, RGB, on a dark
    translucent-looking panel ``width_px`` wide."""

    def __init__(self, ground_rgb: GroundTexture, width_px: int = 300, pad: int = 8) -> None:
        self.view = TopDownView(ground_rgb, width_px=width_px - 2 * pad)
        h, w = self.view.base.shape[:2]
        self.pad = pad
        self.base = np.empty((h + 2 * pad, w + 2 * pad, 3), np.uint8)
        self.base[:] = (14, 16, 22)
        dimmed = (self.view.base.astype(np.uint16) * 3 // 4).astype(np.uint8)
        self.base[pad : pad + h, pad : pad + w] = dimmed

    @property
    def shape(self) -> tuple[int, int]:
        return self.base.shape[:2]

    def render(
        self,
        cars: Sequence[tuple[float, float, tuple[int, int, int]]],
        bots: Sequence[RaceObject] = (),
        highlight: int | None = None,
    ) -> np.ndarray:
        """The map with a dot at each ``(x, y, rgb)`` car (``highlight``: the index of the
        car the camera follows, ringed) and a small grey dot at each bot."""
        img = self.base.copy()
        scale, pad = self.view.scale, self.pad
        to_px = self.view.ground.to_pixels
        for bot in bots:
            px, py = to_px(np.array([[bot.x, bot.y]]))[0] * scale + pad
            cv2.circle(img, (int(px), int(py)), 4, (170, 170, 178), -1, cv2.LINE_AA)
        for i, (x, y, rgb) in enumerate(cars):
            px, py = to_px(np.array([[x, y]]))[0] * scale + pad
            centre = (int(round(px)), int(round(py)))
            if i == highlight:
                cv2.circle(img, centre, 11, (255, 255, 255), 2, cv2.LINE_AA)
            cv2.circle(img, centre, 7, tuple(int(c) for c in rgb), -1, cv2.LINE_AA)
            cv2.circle(img, centre, 7, (20, 20, 20), 1, cv2.LINE_AA)
        return img
