"""What a race puts on the track: DeepRacer's race types and their object settings.

:class:`RaceConfig` is a small, JSON-able description (``to_dict`` / ``from_dict``) that the
training side sends to worker processes; it validates itself and raises ``ValueError`` with a
clear message. The numbers follow DeepRacer's simulator (SimApp) and console:

- ``OBJECT_AVOIDANCE``: 1-6 boxes the size of the DeepRacer package. Either at fixed
  ``object_positions`` (``(track fraction, lane)``, lane 1 = inner, -1 = outer; fractions in
  0.07-0.90 at least 0.13 apart, the console's rules) or placed by the simulator: evenly spaced
  from ``min_object_gap_m`` to 1 m before the end of the lap, lanes alternating inner first;
  with ``randomize_objects`` each episode moves every box at random keeping the gap and picks a
  random lane.
- ``HEAD_TO_BOT``: 1-6 bot cars driving their lane at ``bot_speed`` (0.2-6 m/s), placed like
  the boxes with ``min_bot_gap_m`` (2 m) between them; with ``bot_lane_change`` each bot
  changes lane after a random wait of ``lane_change_min_s``-``lane_change_max_s`` seconds,
  over :data:`LANE_CHANGE_DISTANCE_M`.
- ``TIME_TRIAL``: nothing on the track.

SimApp reads its box gap (``MIN_DISTANCE_BETWEEN_OBSTACLES``) as a percentage of the track
length while documenting metres; here both gaps are metres.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from enum import Enum
from typing import Any


class RaceType(str, Enum):
    """DeepRacer's race type ids."""

    TIME_TRIAL = "TIME_TRIAL"
    OBJECT_AVOIDANCE = "OBJECT_AVOIDANCE"
    HEAD_TO_BOT = "HEAD_TO_BOT"


LANE_INNER = 1
LANE_OUTER = -1
MAX_OBJECTS = 6
"""Most boxes (object avoidance) or bot cars (head-to-bot) on a track."""
MIN_BOT_SPEED = 0.2
MAX_BOT_SPEED = 6.0
"""Bot car speeds DeepRacer's community races allow, m/s."""
FIXED_POSITION_MIN = 0.07
FIXED_POSITION_MAX = 0.90
FIXED_POSITION_GAP = 0.13
"""The console's rules for fixed box positions, as fractions of the centre-line length."""
LANE_CHANGE_DISTANCE_M = 1.0
"""Distance a bot car travels while it changes lane, metres (SimApp's default)."""


@dataclass(frozen=True)
class RaceConfig:
    """A race: its type and the objects on the track. Distances in metres, times in seconds,
    speeds in m/s. Raises ``ValueError`` for a setting DeepRacer would refuse."""

    race_type: RaceType = RaceType.TIME_TRIAL
    number_of_objects: int = 3
    randomize_objects: bool = False
    object_positions: tuple[tuple[float, int], ...] = ()
    min_object_gap_m: float = 2.0
    number_of_bots: int = 2
    bot_speed: float = 0.2
    bot_lane_change: bool = False
    lane_change_min_s: float = 3.0
    lane_change_max_s: float = 5.0
    randomize_bots: bool = False
    min_bot_gap_m: float = 2.0

    def __post_init__(self) -> None:
        try:
            race_type = RaceType(self.race_type)
        except ValueError:
            choices = ", ".join(t.value for t in RaceType)
            raise ValueError(
                f"race_type must be one of {choices}, not {self.race_type!r}"
            ) from None
        object.__setattr__(self, "race_type", race_type)
        positions = tuple((float(f), int(lane)) for f, lane in self.object_positions)
        object.__setattr__(self, "object_positions", positions)
        if positions:
            object.__setattr__(self, "number_of_objects", len(positions))
        _check_count("number_of_objects", self.number_of_objects)
        _check_count("number_of_bots", self.number_of_bots)
        _check_positions(positions)
        if not MIN_BOT_SPEED <= self.bot_speed <= MAX_BOT_SPEED:
            raise ValueError(
                f"bot_speed must be {MIN_BOT_SPEED}-{MAX_BOT_SPEED} m/s, not {self.bot_speed}"
            )
        if not 0 < self.lane_change_min_s <= self.lane_change_max_s:
            raise ValueError(
                "lane change times need 0 < lane_change_min_s <= lane_change_max_s; got "
                f"{self.lane_change_min_s} and {self.lane_change_max_s}"
            )
        for name in ("min_object_gap_m", "min_bot_gap_m"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, not {getattr(self, name)}")

    @property
    def has_boxes(self) -> bool:
        return self.race_type is RaceType.OBJECT_AVOIDANCE

    @property
    def has_bots(self) -> bool:
        return self.race_type is RaceType.HEAD_TO_BOT

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types: the race type as its id, positions as ``[fraction, lane]`` lists."""
        data = asdict(self)
        data["race_type"] = self.race_type.value
        data["object_positions"] = [[f, lane] for f, lane in self.object_positions]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RaceConfig:
        """The inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown race setting(s): {', '.join(unknown)}")
        values = dict(data)
        if "object_positions" in values:
            try:
                values["object_positions"] = tuple(
                    (float(f), int(lane)) for f, lane in values["object_positions"]
                )
            except (TypeError, ValueError):
                raise ValueError(
                    "object_positions must be a list of [track fraction, lane] pairs"
                ) from None
        return cls(**values)


def _check_count(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_OBJECTS:
        raise ValueError(f"{name} must be an integer from 1 to {MAX_OBJECTS}, not {value!r}")


def _check_positions(positions: tuple[tuple[float, int], ...]) -> None:
    for fraction, lane in positions:
        if lane not in (LANE_INNER, LANE_OUTER):
            raise ValueError(f"a lane is 1 (inner) or -1 (outer), not {lane}")
        if not FIXED_POSITION_MIN <= fraction <= FIXED_POSITION_MAX:
            raise ValueError(
                f"object position {fraction} is outside {FIXED_POSITION_MIN}-{FIXED_POSITION_MAX}"
                " of the track"
            )
    ordered = sorted(f for f, _ in positions)
    for a, b in zip(ordered, ordered[1:], strict=False):
        if b - a < FIXED_POSITION_GAP - 1e-9:
            raise ValueError(
                f"object positions {a} and {b} are closer than {FIXED_POSITION_GAP} of the track"
            )
