"""What the car sees: DeepRacer's front camera (mono or stereo), fast.

The track is flat, so a camera's view of the ground is a homography of the top-down ground
texture: one ``cv2.warpPerspective`` per frame instead of rendering a 3-D scene. Rows above the
horizon show a fixed backdrop. Boxes and bot cars are drawn over the warped ground as shaded
solid boxes (:mod:`racing.drawing`), nearer ones over farther ones; with no objects the frame
costs exactly the warp.

:class:`ReferenceCamera` renders the same view through PyBullet's ``getCameraImage``; it is far
slower and exists to check the fast path and to measure it against.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from racing.car import Pose
from racing.drawing import MAX_DRAW_DISTANCE_M, BoxSet, draw_boxes
from racing.lidar import SENSOR_DISCRETIZED_LIDAR, SENSOR_LIDAR, SENSOR_SECTOR_LIDAR
from racing.objects import KIND_BOX, RaceObject
from racing.quiet_pybullet import pb
from racing.texture import WALL_GRAY, WALL_RGB, GroundTexture, render_ground
from racing.track import Track

CAMERA_WIDTH = 160
CAMERA_HEIGHT = 120
CAMERA_HFOV_DEG = math.degrees(1.13)
"""DeepRacer's simulated front camera, 160×120 grayscale at 15 fps: SimApp's Gazebo sensor
(``zed_camera_left_sensor`` in ``urdf/deepracer/racecar.gazebo``) has ``horizontal_fov`` 1.13 rad
(64.7°) at 640×480 with no distortion, an image the agent sees shrunk to 160×120. (The physical
car's lens is wider; the models are trained on the simulator's.)"""
CAMERA_X_M = 0.225
"""Camera position ahead of the car's origin (rear-axle middle), metres. SimApp's racecar URDF
(``urdf/deepracer/deepracer_single_cam_lidar.urdf``): ``camera_link`` sits 0.0448 m ahead of and
0.04 m above ``zed_camera_link``, which ``zed_camera_joint`` puts 0.0917 m ahead of and 0.0800 m
above the chassis, pitched down 0.2618 rad (15°); the chassis is 0.0817 m ahead of the rear
axle. The URDF's front wheel centres sit 4 mm lower in the chassis than the rear ones
(0.01176 m vs 0.01575 m, axles 0.164 m apart), so on level ground the body rakes nose-up by
1.4°: the lens is 0.225 m ahead of the rear axle and 0.132 m above the ground (DeepRacer's
0.035 m wheels), looking 13.6° down."""
CAMERA_HEIGHT_M = 0.132
CAMERA_PITCH_DEG = 15.0 - math.degrees(math.atan2(0.01575 - 0.011759, 0.082311 + 0.081663))
"""Camera tilt below the horizontal, degrees: the URDF's 15° less the body's 1.4° rake. The
horizon is then 24% from the top of the frame, as on DeepRacer's frames, and the centre-line
dashes on them, projected back to the ground, come out evenly spaced (~10 cm, as
:data:`racing.texture.CENTRE_DASH_M` paints them; at 15° they would shrink with distance)."""
STEREO_BASELINE_M = 0.06
"""Distance between the two lenses of the stereo camera, metres (SimApp's
``deepracer_stereo_cam.urdf``: the two ``zed_camera_joint``s at ±0.03 m, otherwise as the single
camera's)."""

SENSOR_CAMERA = "FRONT_FACING_CAMERA"
SENSOR_STEREO = "STEREO_CAMERAS"
CAMERA_SENSORS = (SENSOR_CAMERA, SENSOR_STEREO)
LIDAR_SENSORS = (SENSOR_LIDAR, SENSOR_SECTOR_LIDAR, SENSOR_DISCRETIZED_LIDAR)
SUPPORTED_SENSORS = CAMERA_SENSORS + LIDAR_SENSORS
FRUSTUM_NEAR_M = 0.2
"""DeepRacer's camera frustum starts this far in front of the lens (``object_in_camera``)."""


class SensorError(ValueError):
    """An unsupported or badly combined sensor configuration."""


def validate_sensors(sensors: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Check a DeepRacer ``sensor`` list and return it upper-cased, camera first.

    DeepRacer's combinations: one camera (``FRONT_FACING_CAMERA`` or ``STEREO_CAMERAS``),
    optionally with one LIDAR (``LIDAR``, ``SECTOR_LIDAR`` or ``DISCRETIZED_SECTOR_LIDAR``).
    Raises :class:`SensorError` naming what is wrong with any other list.
    """
    sensors = tuple(s.upper() for s in sensors)
    cameras = [s for s in sensors if s in CAMERA_SENSORS]
    lidars = [s for s in sensors if s in LIDAR_SENSORS]
    unknown = [s for s in sensors if s not in SUPPORTED_SENSORS]
    if unknown:
        raise SensorError(f"unknown sensor {unknown[0]!r}; known: {', '.join(SUPPORTED_SENSORS)}")
    if len(cameras) != 1:
        raise SensorError(
            "choose exactly one camera, FRONT_FACING_CAMERA or STEREO_CAMERAS "
            f"(optionally with one LIDAR); got {list(sensors)}"
        )
    if len(lidars) > 1:
        raise SensorError(f"choose at most one LIDAR sensor; got {', '.join(lidars)}")
    return (cameras[0], *lidars)


@dataclass(frozen=True)
class CameraMount:
    """Where a camera sits on the car and how it looks."""

    forward: float = CAMERA_X_M
    left: float = 0.0
    height: float = CAMERA_HEIGHT_M
    pitch_deg: float = CAMERA_PITCH_DEG
    hfov_deg: float = CAMERA_HFOV_DEG
    width: int = CAMERA_WIDTH
    height_px: int = CAMERA_HEIGHT
    yaw_deg: float = 0.0
    """The lens turned left of the car's heading on its mount (conditions' mount offsets)."""


def intrinsics(mount: CameraMount) -> np.ndarray:
    f = (mount.width / 2) / math.tan(math.radians(mount.hfov_deg) / 2)
    return np.array(
        [[f, 0, (mount.width - 1) / 2], [0, f, (mount.height_px - 1) / 2], [0, 0, 1]],
        dtype=np.float64,
    )


def camera_frame(pose: Pose, mount: CameraMount) -> tuple[np.ndarray, np.ndarray]:
    """World position ``C`` and world→camera rotation ``R`` (OpenCV axes: x right, y down,
    z forward) of a camera on a car at ``pose``. Only the car's yaw (and the mount's
    ``yaw_deg``) turns the camera."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    pos = np.array(
        [
            pose.x + c * mount.forward - s * mount.left,
            pose.y + s * mount.forward + c * mount.left,
            mount.height,
        ]
    )
    if mount.yaw_deg:  # the lens turned on its mount: where it looks, not where it is
        look = pose.yaw + math.radians(mount.yaw_deg)
        c, s = math.cos(look), math.sin(look)
    pitch = math.radians(mount.pitch_deg)
    cp, sp = math.cos(pitch), math.sin(pitch)
    rot = np.array(
        [
            [s, -c, 0.0],  # right
            [-sp * c, -sp * s, -cp],  # down = forward × right
            [c * cp, s * cp, -sp],  # forward
        ]
    )
    return pos, rot


def _backdrop(height: int, width: int, channels: int) -> np.ndarray:
    """What the camera sees above the ground: DeepRacer's dark walls round its tracks (gray
    ~2-25 on its frames), one flat colour (drawn once; a frame only copies it)."""
    if channels == 1:
        return np.full((height, width), WALL_GRAY, dtype=np.uint8)
    return np.broadcast_to(np.array(WALL_RGB, dtype=np.uint8), (height, width, 3)).copy()


class PinholeCamera:
    """A camera on the car that sees the flat ground texture through a homography."""

    def __init__(self, ground: GroundTexture, mount: CameraMount | None = None) -> None:
        self.ground = ground
        self.mount = mount or CameraMount()
        self.K = intrinsics(self.mount)
        self._k_inv = np.linalg.inv(self.K)
        channels = 1 if ground.image.ndim == 2 else 3
        h, w = self.mount.height_px, self.mount.width
        # The horizon row is fixed because the camera only yaws with the car.
        pitch = math.radians(self.mount.pitch_deg)
        horizon = self.K[1, 2] - self.K[1, 1] * math.tan(pitch)
        self.first_ground_row = min(h, max(0, int(math.floor(horizon)) + 2))
        self._frame = _backdrop(h, w, channels)
        self._shift = np.array(
            [[1, 0, 0], [0, 1, self.first_ground_row], [0, 0, 1]], dtype=np.float64
        )
        self._world_to_tex = ground.world_to_pixel
        self._border = ground.floor_value

    def ground_map(self, pose: Pose) -> np.ndarray:
        """3×3 matrix from output pixels (below the horizon) to ground-texture pixels."""
        pos, rot = camera_frame(pose, self.mount)
        rays = rot.T @ self._k_inv  # pixel -> world ray direction
        cz = pos[2]
        to_ground = np.array([[-cz, 0, pos[0]], [0, -cz, pos[1]], [0, 0, 1.0]])
        return self._world_to_tex @ to_ground @ rays @ self._shift

    def render(self, pose: Pose, objects: Sequence[RaceObject] = ()) -> np.ndarray:
        """The camera image at ``pose``: ``(H, W)`` uint8 for grayscale ground, else RGB,
        with ``objects`` drawn over the ground."""
        frame = self._frame.copy()
        row0 = self.first_ground_row
        if row0 < self.mount.height_px:
            cv2.warpPerspective(
                self.ground.image,
                self.ground_map(pose),
                (self.mount.width, self.mount.height_px - row0),
                dst=frame[row0:],
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=self._border,
            )
        if objects:
            self.draw(frame, pose, BoxSet.of(objects))
        return frame

    def draw(self, frame: np.ndarray, pose: Pose, boxes: BoxSet) -> None:
        """Paint ``boxes`` into this camera's ``frame`` seen from a car at ``pose``."""
        pos, rot = camera_frame(pose, self.mount)
        draw_boxes(frame, self.K, pos, rot, boxes)

    def sees(self, pose: Pose, obj: RaceObject) -> bool:
        """Whether ``obj`` is in this camera's frustum: its centre or a corner of its footprint
        projects into the image at least :data:`FRUSTUM_NEAR_M` in front of the lens (the
        test DeepRacer makes for ``object_in_camera``). Plain floats: five points."""
        m = self.mount
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        cam_x = pose.x + c * m.forward - s * m.left
        cam_y = pose.y + s * m.forward + c * m.left
        if m.yaw_deg:  # the lens turned on its mount: where it looks, not where it is
            look = pose.yaw + math.radians(m.yaw_deg)
            c, s = math.cos(look), math.sin(look)
        pitch = math.radians(m.pitch_deg)
        cp, sp = math.cos(pitch), math.sin(pitch)
        fx, cx, fy, cy = self.K[0, 0], self.K[0, 2], self.K[1, 1], self.K[1, 2]
        oc, os_ = math.cos(obj.heading), math.sin(obj.heading)
        hl, hw = obj.length / 2, obj.width / 2
        for a, b in ((0.0, 0.0), (hl, hw), (hl, -hw), (-hl, hw), (-hl, -hw)):
            dx = obj.x + oc * a - os_ * b - cam_x
            dy = obj.y + os_ * a + oc * b - cam_y
            dz = -m.height
            depth = c * cp * dx + s * cp * dy - sp * dz
            if depth < FRUSTUM_NEAR_M:
                continue
            u = fx * (s * dx - c * dy) / depth + cx
            v = fy * (-sp * c * dx - sp * s * dy - cp * dz) / depth + cy
            if 0 <= u <= m.width - 1 and 0 <= v <= m.height_px - 1:
                return True
        return False

    def project(self, pose: Pose, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points ``(N, 3)`` to pixels ``(N, 2)`` and their depth in front of the lens."""
        pos, rot = camera_frame(pose, self.mount)
        cam = (np.asarray(points, dtype=np.float64) - pos) @ rot.T
        depth = cam[:, 2]
        uvw = cam @ self.K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            pix = uvw[:, :2] / uvw[:, 2:3]
        return pix, depth


class CameraSensor:
    """DeepRacer's camera observation: mono ``(120, 160, 1)`` or stereo ``(120, 160, 2)``."""

    def __init__(self, ground_gray: GroundTexture, kind: str = SENSOR_CAMERA) -> None:
        if ground_gray.image.ndim != 2:
            raise SensorError("the camera sensor needs a grayscale ground texture")
        self.kind = kind
        if kind == SENSOR_STEREO:
            half = STEREO_BASELINE_M / 2
            self.cameras = [
                PinholeCamera(ground_gray, CameraMount(left=half)),
                PinholeCamera(ground_gray, CameraMount(left=-half)),
            ]
        elif kind == SENSOR_CAMERA:
            self.cameras = [PinholeCamera(ground_gray)]
        else:
            raise SensorError(f"{kind!r} is not a camera")
        self.shape = (CAMERA_HEIGHT, CAMERA_WIDTH, len(self.cameras))
        self._drawn: tuple[Sequence[RaceObject], BoxSet | None] = ((), None)
        """The last objects drawn (static boxes are the same tuple all episode), as a BoxSet."""

    def observe(self, pose: Pose, objects: Sequence[RaceObject] = ()) -> np.ndarray:
        """The observation ``(120, 160, C)`` uint8 at ``pose`` with ``objects`` in view."""
        frames = [cam.render(pose) for cam in self.cameras]
        if objects:
            if objects is not self._drawn[0]:  # static boxes: the same tuple all episode
                if any(o.kind != KIND_BOX for o in objects):
                    objects = [o for o in objects if _maybe_in_view(pose, o)]  # moving: now
                self._drawn = (objects, BoxSet.of(objects) if objects else None)
            boxes = self._drawn[1]
            if boxes is not None:
                for cam, frame in zip(self.cameras, frames, strict=True):
                    cam.draw(frame, pose, boxes)
        if len(frames) == 1:
            return frames[0][..., None]
        return np.stack(frames, axis=-1)

    def sees(self, pose: Pose, obj: RaceObject) -> bool:
        """Whether any lens has ``obj`` in its frustum."""
        return any(cam.sees(pose, obj) for cam in self.cameras)


def _maybe_in_view(pose: Pose, obj: RaceObject) -> bool:
    """False only for an object no front camera can see: behind the lenses or beyond the
    drawing distance (a cheap first cut for objects that move every step)."""
    dx, dy = obj.x - pose.x, obj.y - pose.y
    radius = math.hypot(obj.length, obj.width, obj.height) / 2
    ahead = dx * math.cos(pose.yaw) + dy * math.sin(pose.yaw)
    return ahead > CAMERA_X_M - radius and math.hypot(dx, dy) < MAX_DRAW_DISTANCE_M + radius


_ground_cache: dict[tuple[int, float, bool], GroundTexture] = {}


def ground_for(track: Track, *, resolution: float, rgb: bool) -> GroundTexture:
    """The ground texture of a track, painted once per process and shared by every env."""
    key = (id(track._rows), resolution, rgb)  # both directions share the same rows
    tex = _ground_cache.get(key)
    if tex is None:
        if len(_ground_cache) > 16:
            _ground_cache.clear()
        tex = render_ground(track, resolution=resolution, rgb=rgb)
        _ground_cache[key] = tex
    return tex


class ReferenceCamera:
    """The front camera rendered by PyBullet's TinyRenderer (``getCameraImage``).

    It puts a textured quad showing the same ground texture into the car's PyBullet world and
    renders the camera view from it: slow, and used only to check and benchmark the fast path.
    """

    def __init__(self, client, ground_rgb: GroundTexture, mount: CameraMount | None = None):
        self.client = client
        self.mount = mount or CameraMount()
        self._dir = tempfile.mkdtemp(prefix="racecraft-ref-")
        image = ground_rgb.image
        h, w = image.shape[:2]
        scale = min(1.0, 4096 / max(h, w))
        if scale < 1.0:
            image = cv2.resize(
                image, (int(w * scale), int(h * scale)), interpolation=cv2.INTER_AREA
            )
        png = os.path.join(self._dir, "ground.png")
        cv2.imwrite(png, cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        x0, y1, res = ground_rgb.x0, ground_rgb.y1, ground_rgb.resolution
        x1, y0 = x0 + w * res, y1 - h * res
        obj = os.path.join(self._dir, "ground.obj")
        with open(obj, "w") as fh:
            fh.write(
                f"v {x0} {y0} 0\nv {x1} {y0} 0\nv {x1} {y1} 0\nv {x0} {y1} 0\n"
                "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n"
                "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n"
            )
        visual = client.createVisualShape(pb.GEOM_MESH, fileName=obj, meshScale=[1, 1, 1])
        body = client.createMultiBody(0, -1, visual, [0, 0, 0.0005])
        texture = client.loadTexture(png)
        client.changeVisualShape(body, -1, textureUniqueId=texture, rgbaColor=[1, 1, 1, 1])
        k = intrinsics(self.mount)
        vfov = math.degrees(2 * math.atan((self.mount.height_px / 2) / k[1, 1]))
        self._projection = client.computeProjectionMatrixFOV(
            vfov, self.mount.width / self.mount.height_px, 0.01, 60.0
        )

    def render(self, pose: Pose) -> np.ndarray:
        """The grayscale camera image ``(H, W)`` uint8 at ``pose``."""
        pos, rot = camera_frame(pose, self.mount)
        fwd, down = rot[2], rot[1]
        view = self.client.computeViewMatrix(pos.tolist(), (pos + fwd).tolist(), (-down).tolist())
        _, _, rgba, _, _ = self.client.getCameraImage(
            self.mount.width,
            self.mount.height_px,
            view,
            self._projection,
            renderer=pb.ER_TINY_RENDERER,
            lightDirection=[0, 0, 1],
            shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK,
        )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(self.mount.height_px, self.mount.width, 4)
        return cv2.cvtColor(rgb[..., :3], cv2.COLOR_RGB2GRAY)
