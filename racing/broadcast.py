"""The broadcast view of a head-to-head race: the whole track from above with every car and bot
on it, and a timing tower beside it (race clock, laps, positions, last laps, who is out).

One frame serves every viewer: the race encodes it once (the MP4 and the live race page show
the same pictures). 1280×720 by default, so it fills a 1920×1080 screen scaled up cleanly.
"""

from __future__ import annotations

import cv2
import numpy as np

from racing.headtohead import CarState, HeadToHeadRace, RaceCar
from racing.sensors import ground_for
from racing.video import TopDownView

BROADCAST_WIDTH, BROADCAST_HEIGHT = 1280, 720
TOWER_WIDTH = 400
"""Width of the timing tower on the right, pixels."""
BACKGROUND_RGB = (18, 20, 26)
TEXT_RGB = (236, 238, 242)
DIM_RGB = (150, 156, 168)
WINNER_RGB = (255, 204, 0)
VIEW_RESOLUTION_M = 0.01
FONT = cv2.FONT_HERSHEY_DUPLEX


def race_clock(seconds: float) -> str:
    """``m:ss.s`` for the race clock and lap times."""
    minutes, rest = divmod(max(0.0, seconds), 60.0)
    return f"{int(minutes)}:{rest:04.1f}"


class BroadcastView:
    """Frames of one race for people, ``(height, width, 3)`` RGB uint8."""

    def __init__(
        self,
        race: HeadToHeadRace,
        *,
        width: int = BROADCAST_WIDTH,
        height: int = BROADCAST_HEIGHT,
        title: str = "",
    ) -> None:
        self.race = race
        self.width, self.height = width, height
        self.title = title
        ground = ground_for(race.track, resolution=VIEW_RESOLUTION_M, rgb=True)
        gh, gw = ground.image.shape[:2]
        area_w, area_h = width - TOWER_WIDTH - 20, height - 20
        fit = min(area_w, int(area_h * gw / gh))
        self.view = TopDownView(ground, width_px=fit)
        vh, vw = self.view.base.shape[:2]
        self.origin = (10 + (area_w - vw) // 2, 10 + (area_h - vh) // 2)
        self.canvas = np.empty((height, width, 3), np.uint8)
        self.canvas[:] = BACKGROUND_RGB

    def render(self) -> np.ndarray:
        """The race now: a new array each call."""
        race = self.race
        frame = self.canvas.copy()
        img = self.view.base.copy()
        for bot in race.bots:
            self.view.draw_object(img, bot)
        for car in race.cars:
            if car.on_track:
                self.view.draw_car(img, car.pose, car.colour)
        x0, y0 = self.origin
        frame[y0 : y0 + img.shape[0], x0 : x0 + img.shape[1]] = img
        self._tower(frame)
        return frame

    def _tower(self, frame: np.ndarray) -> None:
        race = self.race
        left = self.width - TOWER_WIDTH
        laps = race.rules.laps
        leader = race.standings()[0]
        lap = min(laps, leader.laps_done + (0 if leader.state is CarState.FINISHED else 1))
        y = 44
        if self.title:
            _text(frame, self.title[:28], (left, y), 0.7, DIM_RGB)
            y += 40
        _text(frame, race_clock(race.clock_s), (left, y + 20), 1.6, TEXT_RGB, 2)
        _text(frame, f"LAP {lap}/{laps}", (left + 230, y + 14), 0.8, TEXT_RGB)
        y += 70
        for position, car in enumerate(race.standings(), start=1):
            cv2.rectangle(frame, (left, y - 22), (left + 8, y + 22), car.colour, -1)
            _text(frame, str(position), (left + 18, y + 10), 1.0, TEXT_RGB, 2)
            name = car.racer.name or f"Car {car.index + 1}"
            _text(frame, name[:18], (left + 52, y - 2), 0.65, TEXT_RGB)
            _text(frame, _status_line(car, laps), (left + 52, y + 20), 0.5, DIM_RGB)
            y += 62
        if race.over:
            winner = race.standings()[0]
            if winner.state is CarState.FINISHED:
                name = winner.racer.name or f"Car {winner.index + 1}"
                cv2.rectangle(frame, (left - 10, y), (self.width - 10, y + 70), WINNER_RGB, 2)
                _text(frame, "WINNER", (left, y + 26), 0.6, WINNER_RGB)
                _text(frame, name[:20], (left, y + 58), 0.9, WINNER_RGB, 2)


def _status_line(car: RaceCar, laps: int) -> str:
    records = car.lap_records()
    if car.state is CarState.FINISHED:
        return f"finished {race_clock(car.finish_time_s or 0.0)}"
    if car.state is CarState.OUT:
        return f"out: {car.reason}"[:34]
    done = [lap for lap in records if lap.status.value == "lap_complete"]
    last = f"  last {race_clock(done[-1].time_s)}" if done else ""
    return f"lap {min(laps, car.laps_done + 1)}/{laps}{last}"


def _text(frame, text: str, at: tuple[int, int], scale: float, rgb, thickness: int = 1) -> None:
    cv2.putText(frame, text, at, FONT, scale, rgb, thickness, cv2.LINE_AA)
