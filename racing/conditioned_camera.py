"""The camera under conditions (:mod:`racing.conditions`): the same 160×120 grayscale frame,
seen in another room.

Built once per episode (everything that depends only on the episode's draw is computed here,
not per frame), then per frame:

1. **The ground.** With the ``look`` family or the light's colour ``cast`` set, the camera warps
   a *class* texture instead of the gray one: a code per surface (wall 0, floor 64, border
   line 128, road 192, centre line 255; the start line is a border line), painted with the
   same anti-aliasing as the gray texture, so a pixel between two surfaces holds a code between
   theirs. One 256-entry table built per episode turns codes into gray levels (each surface's
   look and cast; an edge blends the two grays). The same one warp as the clean camera, plus a
   lookup. Otherwise it is the clean gray warp, unchanged. The ``texture`` grain (step 3)
   comes from one of :data:`GRAIN_VIEWS` precomputed views of a grain plane in the camera's
   perspective, drawn per frame: it is not fixed on the ground (a world-fixed grain would
   cost a second warp a frame), which a model that sees one frame at a time cannot tell.
   The ``camera`` family's mount offsets (yaw, pitch, height) move the virtual lens.
2. Boxes and bot cars as the clean camera draws them.
3. **Light and exposure**: one 256-entry lookup table for brightness, contrast, gamma and
   exposure (composed into the look's table when there is one and no object is drawn, so a
   frame costs one lookup). Then the ``texture`` grain, and
   ``glare`` (a bright patch placed per episode) added: light that the tone does not dim.
4. **Camera**: a 3×3 Gaussian ``blur``, then ``noise`` from a fixed Gaussian field scaled once
   per episode and read at a per-frame window drawn (per episode, in advance) from the
   episode's generator: deterministic for a seed, no Gaussian draw per frame.

A family left neutral skips its work, so a frame under conditions that change no image family
is the clean frame byte for byte. :meth:`ConditionedCamera.sees` (DeepRacer's
``object_in_camera`` in ``params``) answers for the true camera: ``params`` describe the car.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np

from racing.car import REPORTED_POINT_AHEAD_M, Pose
from racing.conditions import Conditions
from racing.drawing import BoxSet
from racing.objects import KIND_BOX, RaceObject
from racing.sensors import (
    CAMERA_HEIGHT,
    CAMERA_WIDTH,
    CameraSensor,
    PinholeCamera,
    _maybe_in_view,
)
from racing.texture import (
    BORDER_RGB,
    CENTRE_RGB,
    FLOOR_RGB,
    ROAD_RGB,
    WALL_RGB,
    GroundTexture,
    render_ground,
)
from racing.track import Track

CODES = {"wall": 0, "floor": 64, "line": 128, "road": 192, "centre": 255}
"""Each surface's code in the class texture, in the order surfaces meet on the ground (wall |
floor | border line | road | centre line), so that an anti-aliased edge between neighbours
blends through no third surface's code."""
_SURFACE_RGB = {"wall": WALL_RGB, "floor": FLOOR_RGB, "line": BORDER_RGB, "road": ROAD_RGB,
                "centre": CENTRE_RGB}  # fmt: skip
GRAIN_VIEWS = 4
"""Precomputed views of the ``texture`` grain (:func:`grain_views`); each frame shows one."""
NOISE_FIELD_SIZE = CAMERA_HEIGHT * CAMERA_WIDTH + 8192
"""Values in the precomputed unit Gaussian noise field; each frame reads 120×160 of them in a
row, from an offset drawn per frame."""
NOISE_OFFSETS = 64
"""Per-frame draws (grain view, noise window) made per episode, cycled after that."""
NOISE_MAX = 12.0
TEXTURE_MAX = 40.0
"""The noise field and the grain views are kept as uint8 at these strengths (the widest
ranges' tops) and scaled down per episode."""


def _luma(rgb: Sequence[float]) -> float:
    return 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]


_class_cache: dict[tuple[int, float], GroundTexture] = {}


def class_ground_for(track: Track, *, resolution: float) -> GroundTexture:
    """The class texture of ``track`` (a code per surface, :data:`CODES`), painted once per
    process; the same geometry as :func:`racing.sensors.ground_for`'s gray texture."""
    key = (id(track._rows), resolution)  # both directions share the same rows
    tex = _class_cache.get(key)
    if tex is None:
        if len(_class_cache) > 4:
            _class_cache.clear()
        colours = {k: (CODES[s],) * 3 for k, s in
                   (("floor", "floor"), ("road", "road"), ("border", "line"),
                    ("centre", "centre"), ("start", "line"))}  # fmt: skip
        tex = render_ground(track, resolution=resolution, rgb=False, colours=colours)
        _class_cache[key] = tex
    return tex


_grain_cache: list[np.ndarray] = []


def grain_views() -> np.ndarray:
    """:data:`GRAIN_VIEWS` views ``(N, 120, 160)`` float32 of a grain plane (mottling about
    4 cm across and 5 mm speckle, unit standard deviation) as the front camera sees it from
    different places: the grain's size shrinks towards the horizon as a carpet's does; zero
    above the horizon. Computed once per process."""
    if not _grain_cache:
        rng = np.random.default_rng(0x6A1)
        res, size = 0.005, 1024
        coarse = cv2.resize(rng.standard_normal((size // 8, size // 8)).astype(np.float32),
                            (size, size), interpolation=cv2.INTER_LINEAR)  # fmt: skip
        coarse /= float(coarse.std())
        fine = rng.standard_normal((size, size)).astype(np.float32)
        plane = GroundTexture(0.8 * coarse + 0.6 * fine, 0.0, size * res, res)
        camera = PinholeCamera(GroundTexture(np.zeros((1, 1), np.uint8), 0.0, size * res, res))
        row0 = camera.first_ground_row
        views = np.zeros((GRAIN_VIEWS, CAMERA_HEIGHT, CAMERA_WIDTH), dtype=np.float32)
        for i in range(GRAIN_VIEWS):
            pose = Pose(rng.uniform(1.0, 1.5), rng.uniform(1.0, 4.0), rng.uniform(-0.5, 0.5))
            views[i, row0:] = cv2.warpPerspective(
                plane.image, camera.ground_map(pose), (CAMERA_WIDTH, CAMERA_HEIGHT - row0),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT,
            )  # fmt: skip
        _grain_cache.append(views)
    return _grain_cache[0]


def surface_grays(conditions: Conditions) -> dict[str, float]:
    """Each surface's gray level under the episode's look and colour cast: the surface keeps
    DeepRacer's hue, scaled to the look's gray; the cast scales red up and blue down."""
    look, cast = conditions.values["look"], conditions.values["light"]["cast"]
    grays = {}
    for surface, rgb in _SURFACE_RGB.items():
        target = look[surface]
        if cast == 0.0:
            grays[surface] = target
            continue
        r, g, b = (v * target / _luma(rgb) for v in rgb)
        r, b = min(255.0, r * (1 + cast)), min(255.0, b * (1 - cast))
        grays[surface] = _luma((r, min(255.0, g), b))
    return grays


def class_table(conditions: Conditions) -> np.ndarray:
    """The 256-entry table from a class code to its gray level (codes between two surfaces'
    blend their grays, as the anti-aliased edge they come from)."""
    grays = surface_grays(conditions)
    gray = np.interp(np.arange(256.0), list(CODES.values()), [grays[s] for s in CODES])
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8)


def _signed(field: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``rint(field * scale)`` as its positive and negative parts, uint8 (for saturating
    ``cv2.add`` and ``cv2.subtract``)."""
    scaled = np.rint(field * scale)
    return (np.clip(scaled, 0, 255).astype(np.uint8), np.clip(-scaled, 0, 255).astype(np.uint8))


_signed_cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def _scaled(name: str, value: float, top: float) -> tuple[np.ndarray, np.ndarray]:
    """The noise field (``"noise"``) or the grain views (``"grain"``) at ``value`` (of at most
    ``top``): the uint8 parts kept at ``top``, scaled with OpenCV (cheap per episode)."""
    parts = _signed_cache.get(name)
    if parts is None:
        field = grain_views() if name == "grain" else _noise_field()
        parts = _signed_cache[name] = _signed(field.reshape(-1, field.shape[-1]), top)
    alpha = value / top
    return (cv2.convertScaleAbs(parts[0], alpha=alpha), cv2.convertScaleAbs(parts[1], alpha=alpha))


def _noise_field() -> np.ndarray:
    """A unit Gaussian field of :data:`NOISE_FIELD_SIZE` values in a row, the same in every
    process: a frame's noise is a window of it (contiguous, so cheap to add)."""
    field = np.random.default_rng(0x5EED).standard_normal(NOISE_FIELD_SIZE)
    return field.astype(np.float32).reshape(1, -1)


def tone_table(conditions: Conditions) -> np.ndarray | None:
    """The 256-entry table for the light's brightness, contrast and gamma and the camera's
    exposure, or ``None`` when all are neutral."""
    light, exposure = conditions.values["light"], conditions.values["camera"]["exposure"]
    b, c, g = light["brightness"], light["contrast"], light["gamma"]
    if b == 0.0 and c == 1.0 and g == 1.0 and exposure == 0.0:
        return None
    x = np.arange(256, dtype=np.float64) / 255.0
    x = np.clip((x - 0.5) * c + 0.5 + b / 255.0, 0.0, 1.0) ** g
    x = np.clip(x * 2.0**exposure, 0.0, 1.0)
    return np.rint(x * 255.0).astype(np.uint8)


GLARE_RADII = (8, 16, 24)
"""A glare patch's radius, pixels: one of these, drawn per episode."""
_glare_cache: dict[int, np.ndarray] = {}


def glare_image(peak: float, rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A ceiling light's reflection: a soft bright patch of ``peak`` gray levels (a Gaussian
    of :data:`GLARE_RADII` /2 standard deviation), centred somewhere in the lower two thirds of
    the frame (on the ground). A window of a unit patch computed once, scaled."""
    radius = GLARE_RADII[int(rng.integers(len(GLARE_RADII)))]
    u = int(rng.integers(int(0.1 * width), int(0.9 * width)))
    v = int(rng.integers(int(0.4 * height), int(0.95 * height)))
    unit = _glare_cache.get(radius)
    if unit is None:  # twice the frame, the patch at its centre, 255 at the peak
        sigma = radius / 2
        gy = np.exp(-((np.arange(2 * height) - height) ** 2) / (2 * sigma**2))
        gx = np.exp(-((np.arange(2 * width) - width) ** 2) / (2 * sigma**2))
        unit = _glare_cache[radius] = np.rint(255 * np.outer(gy, gx)).astype(np.uint8)
    window = unit[height - v : 2 * height - v, width - u : 2 * width - u]
    return cv2.convertScaleAbs(window, alpha=peak / 255.0)


class ConditionedCamera:
    """A :class:`CameraSensor` seen through one episode's ``conditions``: the same
    ``observe(pose, objects)`` and ``shape``. ``rng`` is the episode's generator (glare's place,
    the noise windows); ``track`` gives the class texture when the look or the cast is set."""

    def __init__(
        self,
        base: CameraSensor,
        track: Track,
        conditions: Conditions,
        rng: np.random.Generator,
    ) -> None:
        self.base = base
        self.kind = base.kind
        self.shape = base.shape
        self.conditions = conditions
        light, cam = conditions.values["light"], conditions.values["camera"]
        mounts = [c.mount for c in base.cameras]
        if cam["yaw_deg"] or cam["pitch_deg"] or cam["height_mm"]:
            mounts = [
                replace(m, yaw_deg=m.yaw_deg + cam["yaw_deg"],
                        pitch_deg=m.pitch_deg + cam["pitch_deg"],
                        height=m.height + cam["height_mm"] / 1000.0)
                for m in mounts
            ]  # fmt: skip
        gray = base.cameras[0].ground
        self.cameras = [PinholeCamera(gray, m) for m in mounts]
        h, w = self.shape[:2]
        self._classes: GroundTexture | None = None
        if not conditions.family_is_neutral("look") or light["cast"] != 0.0:
            self._classes = class_ground_for(track, resolution=gray.resolution)
            self._table = class_table(conditions)
            self._code_frame = np.full((h, w), CODES["wall"], dtype=np.uint8)
        texture = conditions.values["look"]["texture"]
        self._grain = _scaled("grain", texture, TEXTURE_MAX) if texture > 0 else None
        self._tone = tone_table(conditions)
        self._toned_table = None
        if self._classes is not None and self._tone is not None:
            self._toned_table = self._tone[self._table]  # one lookup a frame: look and tone
        self._glare = glare_image(light["glare"], rng, h, w) if light["glare"] > 0 else None
        if self._glare is not None and self._grain is not None:  # one addition a frame, not two
            glare = np.tile(self._glare, (GRAIN_VIEWS, 1))
            self._grain = (cv2.add(self._grain[0], glare), self._grain[1])
            self._glare = None
        self._blur = None  # a separable 3-tap Gaussian, its kernel made once (cheaper a frame)
        if cam["blur"] > 0:
            self._blur = cv2.getGaussianKernel(3, float(cam["blur"]), cv2.CV_32F)
        self._noise = _scaled("noise", cam["noise"], NOISE_MAX) if cam["noise"] > 0 else None
        bounds = np.array([GRAIN_VIEWS, NOISE_FIELD_SIZE - h * w + 1])
        self._draws = (rng.random((NOISE_OFFSETS, 2)) * bounds).astype(np.int64).tolist()
        """Per frame: the grain view and where the noise window starts."""
        self._frame_index = 0
        self._drawn: tuple[Sequence[RaceObject], BoxSet | None] = ((), None)

    def observe(self, pose: Pose, objects: Sequence[RaceObject] = ()) -> np.ndarray:
        """The observation ``(120, 160, C)`` uint8 at ``pose`` under the conditions."""
        boxes = None
        if objects:
            if objects is not self._drawn[0]:  # static boxes: the same tuple all episode
                if any(o.kind != KIND_BOX for o in objects):
                    objects = [o for o in objects if _maybe_in_view(pose, o)]
                self._drawn = (objects, BoxSet.of(objects) if objects else None)
            boxes = self._drawn[1]
        # The look's table holds the tone too, unless objects are drawn over the ground: they
        # are toned with it, after.
        toned = self._toned_table is not None and boxes is None
        frames = []
        for cam in self.cameras:
            # Above the ground rows the frame is the flat backdrop (unless objects rise into
            # it): lookups fill it with one value, the blur leaves it alone.
            top = cam.first_ground_row if boxes is None else 0
            frame = self._ground(cam, pose, toned, top)
            if boxes is not None:
                cam.draw(frame, pose, boxes)
            self._finish(frame, toned, top)
            frames.append(frame)
        if len(frames) == 1:
            return frames[0][..., None]
        return np.stack(frames, axis=-1)

    def sees(self, pose: Pose, obj: RaceObject) -> bool:
        """The true camera's answer (``params`` describe the car, not the conditions)."""
        return self.base.sees(pose, obj)

    def _ground(self, cam: PinholeCamera, pose: Pose, toned: bool, top: int) -> np.ndarray:
        if self._classes is None:
            return cam.render(pose)
        frame = self._code_frame.copy()
        row0 = cam.first_ground_row
        h, w = self.shape[:2]
        if row0 < h:
            cv2.warpPerspective(
                self._classes.image,
                cam.ground_map(pose),
                (w, h - row0),
                dst=frame[row0:],
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=CODES["wall"],
            )
        table = self._toned_table if toned else self._table
        cv2.LUT(frame[top:], table, dst=frame[top:])
        frame[:top] = table[CODES["wall"]]
        return frame

    def _finish(self, frame: np.ndarray, toned: bool, top: int) -> None:
        """Tone (unless ``toned``: the look's table held it), grain, glare, blur and noise, in
        place; rows above ``top`` hold the flat backdrop."""
        view, at = self._draws[self._frame_index % NOISE_OFFSETS]
        self._frame_index += 1
        h, w = frame.shape
        if self._tone is not None and not toned:
            cv2.LUT(frame[top:], self._tone, dst=frame[top:])
            frame[:top] = self._tone[frame[0, 0]]
        if self._grain is not None:
            rows = slice(view * h, (view + 1) * h)
            cv2.add(frame, self._grain[0][rows], dst=frame)
            cv2.subtract(frame, self._grain[1][rows], dst=frame)
        if self._glare is not None:
            cv2.add(frame, self._glare, dst=frame)
        if self._blur is not None:
            rows = frame[max(0, top - 2) :]
            cv2.sepFilter2D(rows, -1, self._blur, self._blur, dst=rows)
        if self._noise is not None:
            pos, neg = self._noise
            cv2.add(frame, pos[0, at : at + h * w].reshape(h, w), dst=frame)
            cv2.subtract(frame, neg[0, at : at + h * w].reshape(h, w), dst=frame)


def conditioned(
    base: CameraSensor, track: Track, conditions: Conditions | None, rng: np.random.Generator
) -> CameraSensor | ConditionedCamera:
    """``base`` itself when ``conditions`` change no image family, else a
    :class:`ConditionedCamera` over it."""
    if conditions is None or not conditions.changes_image:
        return base
    return ConditionedCamera(base, track, conditions, rng)


def pose_at(track: Track, fraction: float) -> Pose:
    """The car's pose on the centre line at ``fraction`` (0-1) of the lap, facing along it."""
    s = (float(fraction) % 1.0) * track.length if track.closed else float(fraction) * track.length
    px, py = track.point_at(s)
    yaw = track.heading_at(s)
    return Pose(px - REPORTED_POINT_AHEAD_M * math.cos(yaw),
                py - REPORTED_POINT_AHEAD_M * math.sin(yaw), yaw)  # fmt: skip
