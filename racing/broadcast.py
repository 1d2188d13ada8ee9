"""The broadcast picture of a head-to-head race, made for people.

Each step, :meth:`BroadcastView.render` draws one frame, ``(720, 1280, 3)`` RGB by default:

- the **TV camera** (:class:`racing.video.TVCamera`): behind and above the car the director
  chose (:class:`racing.director.Director`: the leader, a close battle's chaser, an incident),
  with every car and bot on the track;
- a **picture-in-picture** of each racer's own camera, bottom right: exactly the observation
  its model got this step (grayscale 160×120, the first camera of a stereo pair), the last one
  while the car sits out a penalty, dark once it is off the track;
- a **track map** inset in the corner with each car and bot as a coloured dot.

They are drawn into the one frame on purpose: the race encodes one JPEG a step for every
viewer, however many watch. The timing tower, sectors, clock, lap and winner are *not* in the
live picture: the race's timing (:class:`racing.timing.Timing`, computed here once a step)
travels beside it as data (:meth:`BroadcastView.header`) and the page draws them in HTML, placed
by the frame's :meth:`~BroadcastView.layout` (where each PiP and the map are). The MP4 replay
burns the same overlays in, once, from the same timing (:meth:`BroadcastView.replay_frame`,
:func:`draw_timing`).

1280×720 by default: the frame budget of a 15 frames/s race on two cores (the TV camera costs
about 13 ms at 1280×720 and 28 ms at 1920×1080 here); the page scales it to fill 1920×1080.
"""

from __future__ import annotations

import cv2
import numpy as np

from racing.director import Director, Shot
from racing.headtohead import HeadToHeadRace
from racing.sensors import ground_for
from racing.timing import FINISHED, RETIRED, RaceTiming, Timing
from racing.video import TrackMap, TVCamera

BROADCAST_WIDTH, BROADCAST_HEIGHT = 1280, 720
MARGIN = 16
PIP_WIDTH, PIP_HEIGHT, PIP_GAP = 160, 120, 8
MAP_WIDTH, MAP_MAX_HEIGHT = 300, 230
VIEW_RESOLUTION_M = 0.005
TEXT_RGB = (236, 238, 242)
DIM_RGB = (150, 156, 168)
PANEL_RGB = (12, 14, 20)
WINNER_RGB = (255, 204, 0)
FONT = cv2.FONT_HERSHEY_DUPLEX


def race_clock(seconds: float | None) -> str:
    """``m:ss.s`` for the race clock and lap times."""
    if seconds is None:
        return "-"
    minutes, rest = divmod(max(0.0, seconds), 60.0)
    return f"{int(minutes)}:{rest:04.1f}"


class BroadcastView:
    """Frames of one race for people (see the module docstring)."""

    def __init__(
        self,
        race: HeadToHeadRace,
        *,
        width: int = BROADCAST_WIDTH,
        height: int = BROADCAST_HEIGHT,
        title: str = "",
        director: Director | None = None,
    ) -> None:
        self.race = race
        self.width, self.height = width, height
        self.title = title
        ground = ground_for(race.track, resolution=VIEW_RESOLUTION_M, rgb=True)
        self.camera = TVCamera(ground, width=width, height=height)
        self.map = TrackMap(ground, width_px=MAP_WIDTH)
        if self.map.shape[0] > MAP_MAX_HEIGHT:  # a tall track: a narrower map
            wide = int(MAP_WIDTH * MAP_MAX_HEIGHT / self.map.shape[0])
            self.map = TrackMap(ground, width_px=wide)
        self.timing: RaceTiming = race.timing  # the race's own, updated once a step
        self.director = director or Director()
        self.latest: Timing | None = None
        self.shot: Shot | None = None
        mh, mw = self.map.shape
        self.map_at = (width - MARGIN - mw, height - MARGIN - mh)
        n = len(race.cars)
        strip = n * PIP_WIDTH + (n - 1) * PIP_GAP
        x0, y0 = self.map_at[0] - MARGIN - strip, height - MARGIN - PIP_HEIGHT
        self.pips_at = [(x0 + i * (PIP_WIDTH + PIP_GAP), y0) for i in range(n)]
        self._pictures: list[np.ndarray | None] = [None] * n

    # ------------------------------------------------------------------ the live frame
    def render(self, observations: list | None = None) -> np.ndarray:
        """The race now (a new array each call), after computing this step's timing and shot.
        ``observations``: what each car's model sees next (:meth:`HeadToHeadRace.observations`;
        asked of the race when not given)."""
        race = self.race
        self.latest = race.timing.latest or race.timing.update(race)
        previous = self.shot
        self.shot = self.director.decide(self.latest)
        if self.shot is not None and self.shot != previous:
            self.camera.cut()
        objects = race.objects()
        if self.shot is not None:
            pose = race.cars[self.shot.car].pose
            frame = self.camera.render(pose, objects, self.shot.camera)
        else:
            leader = race.standings()[0]
            frame = self.camera.render(leader.pose, objects, "wide")
        if observations is None:
            observations = race.observations()
        self._pips(frame, observations)
        on = [car for car in race.cars if car.on_track]
        followed = self.shot.car if self.shot is not None else None
        highlight = next((k for k, car in enumerate(on) if car.index == followed), None)
        dots = [(car.pose.x, car.pose.y, car.colour) for car in on]
        self._paste(frame, self.map.render(dots, race.bots, highlight), self.map_at)
        return frame

    def _pips(self, frame: np.ndarray, observations: list) -> None:
        for car, obs, at in zip(self.race.cars, observations, self.pips_at, strict=True):
            picture = _camera_image(obs)
            if picture is not None:
                self._pictures[car.index] = picture
            picture = self._pictures[car.index]
            x, y = at
            box = frame[y : y + PIP_HEIGHT, x : x + PIP_WIDTH]
            if picture is None or not car.on_track:
                box[:] = (box.astype(np.uint16) // 4).astype(np.uint8)
                if picture is not None:
                    box[:] = np.maximum(box, (picture[..., None] // 3).astype(np.uint8))
            else:
                box[:] = picture[..., None]
            cv2.rectangle(frame, (x - 2, y - 2), (x + PIP_WIDTH + 1, y + PIP_HEIGHT + 1),
                          car.colour, 2)  # fmt: skip

    @staticmethod
    def _paste(frame: np.ndarray, img: np.ndarray, at: tuple[int, int]) -> None:
        x, y = at
        h, w = img.shape[:2]
        frame[y : y + h, x : x + w] = img

    # ------------------------------------------------------------------ what travels with it
    def layout(self) -> dict:
        """Where the PiPs and the map lie in the frame (pixels), for the page's labels."""
        mh, mw = self.map.shape
        return {
            "width": self.width,
            "height": self.height,
            "map": [*self.map_at, mw, mh],
            "pips": [{"car": car.index, "name": car.racer.name or f"Car {car.index + 1}",
                      "rect": [x, y, PIP_WIDTH, PIP_HEIGHT]}
                     for car, (x, y) in zip(self.race.cars, self.pips_at, strict=True)],
        }  # fmt: skip

    def header(self) -> dict:
        """This step's frame header: the timing, the shot and the layout (plain JSON types;
        names, times and positions only: nothing a spectator may not see)."""
        assert self.latest is not None, "render() first"
        return {
            "timing": self.latest.to_dict(),
            "shot": self.shot.to_dict() if self.shot is not None else None,
            "layout": self.layout(),
            "title": self.title,
        }

    # ------------------------------------------------------------------ the MP4 replay
    def replay_frame(self, frame: np.ndarray) -> np.ndarray:
        """``frame`` with this step's timing burnt in, for the MP4 (a copy)."""
        assert self.latest is not None, "render() first"
        out = frame.copy()
        draw_timing(out, self.latest.to_dict(), title=self.title, layout=self.layout())
        return out


def _camera_image(obs) -> np.ndarray | None:
    """The (120, 160) grayscale picture in an observation (camera, stereo, or with LIDAR)."""
    if obs is None:
        return None
    if isinstance(obs, dict):
        obs = next((v for v in obs.values() if isinstance(v, np.ndarray) and v.ndim == 3), None)
        if obs is None:
            return None
    image = np.asarray(obs)
    if image.ndim == 3:
        image = image[..., 0]
    if image.shape != (PIP_HEIGHT, PIP_WIDTH):
        image = cv2.resize(image, (PIP_WIDTH, PIP_HEIGHT), interpolation=cv2.INTER_AREA)
    return image.astype(np.uint8, copy=False)


def draw_timing(frame: np.ndarray, timing: dict, *, title: str = "",
                layout: dict | None = None) -> None:  # fmt: skip
    """Burn a timing dict (:meth:`racing.timing.Timing.to_dict`) into ``frame``, as the page
    draws it in HTML: the tower on the left, the clock and lap top right, the PiP names, and
    the winner in the centre once the race is over. Only the MP4 uses this."""
    h, w = frame.shape[:2]
    cars = timing.get("cars", [])
    rows = len(cars)
    x0, y0 = MARGIN, MARGIN
    tower_w, row_h = 330, 40
    top = 34 if title else 0
    _panel(frame, x0, y0, tower_w, top + 12 + rows * row_h)
    if title:
        _text(frame, title[:30], (x0 + 12, y0 + 26), 0.6, DIM_RGB)
    y = y0 + top + 12
    for car in cars:
        colour = _rgb(car.get("colour", "#cccccc"))
        cv2.rectangle(frame, (x0 + 8, y + 6), (x0 + 14, y + row_h - 6), colour, -1)
        _text(frame, str(car["position"]), (x0 + 22, y + 28), 0.75, TEXT_RGB, 2)
        _text(frame, car["name"][:14], (x0 + 52, y + 27), 0.6, TEXT_RGB)
        _text(frame, _tower_right(car), (x0 + 222, y + 27), 0.55, DIM_RGB)
        y += row_h
    clock = f"{race_clock(timing.get('clock_s'))}"
    lap = f"LAP {timing.get('lap', 0)}/{timing.get('laps', 0)}"
    _panel(frame, w - MARGIN - 300, MARGIN, 300, 56)
    _text(frame, lap, (w - MARGIN - 288, MARGIN + 38), 0.75, TEXT_RGB, 2)
    _text(frame, clock, (w - MARGIN - 150, MARGIN + 40), 1.0, TEXT_RGB, 2)
    for pip in (layout or {}).get("pips", []):
        x, y, pw, _ = pip["rect"]
        _panel(frame, x, y, pw, 20)
        _text(frame, pip["name"][:16], (x + 4, y + 15), 0.45, TEXT_RGB)
    winner = timing.get("winner")
    if timing.get("over") and winner:
        bw, bh = 520, 130
        bx, by = (w - bw) // 2, (h - bh) // 2 - 60
        _panel(frame, bx, by, bw, bh)
        cv2.rectangle(frame, (bx, by), (bx + bw, by + bh), WINNER_RGB, 2)
        _text(frame, "WINNER", (bx + 20, by + 36), 0.8, WINNER_RGB, 2)
        _text(frame, winner["name"][:22], (bx + 20, by + 84), 1.2, TEXT_RGB, 2)
        if winner.get("time_s") is not None:
            _text(frame, race_clock(winner["time_s"]), (bx + 20, by + 118), 0.7, DIM_RGB)


def _tower_right(car: dict) -> str:
    if car["status"] == FINISHED:
        return race_clock(car.get("finish_s"))
    if car["status"] == RETIRED:
        return "OUT"
    if car.get("gap_s") is not None:
        return f"+{car['gap_s']:.1f}s"
    return f"L{car['lap']}"


def _panel(frame: np.ndarray, x: int, y: int, w: int, h: int) -> None:
    region = frame[max(0, y) : y + h, max(0, x) : x + w]
    region[:] = (region.astype(np.uint16) * 2 // 7 + np.array(PANEL_RGB) * 5 // 7).astype(np.uint8)


def _rgb(hex_colour: str) -> tuple[int, int, int]:
    value = hex_colour.lstrip("#")
    try:
        return tuple(int(value[i : i + 2], 16) for i in (0, 2, 4))  # type: ignore[return-value]
    except ValueError:
        return (200, 200, 200)


def _text(frame, text: str, at: tuple[int, int], scale: float, rgb, thickness: int = 1) -> None:
    cv2.putText(frame, text, at, FONT, scale, rgb, thickness, cv2.LINE_AA)
