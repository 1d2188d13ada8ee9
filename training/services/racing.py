"""Race types and their settings: the rules the wizard, the evaluation form and the league ask.

A model (and an evaluation) stores its race type and, for object avoidance and head-to-bot,
the race's settings as :meth:`racing.race.RaceConfig.to_dict` gives them (``race_config``);
the jobs hand that dict to the simulator through :class:`training.rollout.envs.EnvSpec`. The
numbers (1-6 boxes or bots, bot speed 0.2-6 m/s, fixed positions 0.07-0.90 of the lap at least
0.13 apart, lane-change times) are the simulator's (:mod:`racing.race`); here they become
:class:`~training.errors.ServiceError` s naming the form field, and the sensors DeepRacer
recommends per race type become advice.
"""

from __future__ import annotations

from typing import Any

from racing.race import RaceConfig
from training.errors import ServiceError
from training.models import RaceType

SUPPORTED_RACE_TYPES = (RaceType.TIME_TRIAL, RaceType.OBJECT_AVOIDANCE, RaceType.HEAD_TO_BOT)
BOX_SETTINGS = ("number_of_objects", "randomize_objects", "object_positions")
BOT_SETTINGS = ("number_of_bots", "bot_speed", "bot_lane_change", "lane_change_min_s",
                "lane_change_max_s", "randomize_bots")  # fmt: skip
SETTINGS_OF = {
    RaceType.TIME_TRIAL: (),
    RaceType.OBJECT_AVOIDANCE: BOX_SETTINGS + ("min_object_gap_m",),
    RaceType.HEAD_TO_BOT: BOT_SETTINGS + ("min_bot_gap_m",),
}
"""The settings each race type takes (others are refused, so a typo is never ignored)."""
RACE_DEFAULTS = {"number_of_objects": 3, "number_of_bots": 2, "bot_speed": 0.5,
                 "lane_change_min_s": 3.0, "lane_change_max_s": 5.0}  # fmt: skip
"""What a new race starts from where the user gives nothing: in the wizard, the evaluation
form, the league and the command line alike. All are the simulator's (DeepRacer's) own but the
bot speed: 0.5 m/s, not the simulator's 0.2, as DeepRacer's guide suggests (bots at 0.4-0.5 m/s
against a car at 0.8-1 m/s); at 0.2 m/s a bot car is nearly a box."""
_FIELD_OF_WORD = (
    ("object_positions", "object_positions"),
    ("object position", "object_positions"),
    ("a lane is", "object_positions"),
    ("number_of_objects", "number_of_objects"),
    ("number_of_bots", "number_of_bots"),
    ("bot_speed", "bot_speed"),
    ("lane change", "lane_change_min_s"),
)


def race_settings(race_type: str, settings: dict[str, Any] | None = None) -> dict[str, Any]:
    """The stored form of a race's settings: ``{}`` for a time trial, else the race type and
    its own settings from ``RaceConfig.to_dict()`` (:data:`RACE_DEFAULTS`, then the
    simulator's, filled in), so the stored form is accepted again as it is. Raises
    :class:`ServiceError` on the field of the first bad setting."""
    check_race_type(race_type)
    settings = dict(settings or {})
    settings.pop("race_type", None)
    allowed = SETTINGS_OF[RaceType(race_type)]
    unknown = sorted(k for k in settings if k not in allowed)
    if unknown:
        label = RaceType(race_type).label
        raise ServiceError(f"{label} has no setting {unknown[0]!r}", field="race_type")
    if race_type == RaceType.TIME_TRIAL:
        return {}
    defaults = {k: v for k, v in RACE_DEFAULTS.items() if k in allowed}
    try:
        config = RaceConfig.from_dict({"race_type": race_type, **defaults, **settings})
    except (ValueError, TypeError) as exc:
        raise ServiceError(str(exc), field=_field_for(str(exc))) from None
    stored = config.to_dict()
    return {k: v for k, v in stored.items() if k == "race_type" or k in allowed}


def parse_object_positions(text: str) -> list[list[float | int]]:
    """DeepRacer-for-Cloud's ``OBJECT_POSITIONS`` text, ``"0.23,-1;0.46,1"`` (track fraction,
    lane: 1 inner, -1 outer), as ``[[0.23, -1], [0.46, 1]]``; blank = ``[]`` (placed by the
    simulator). The ranges are checked by :func:`race_settings`."""
    positions: list[list[float | int]] = []
    for n, part in enumerate(p for p in text.replace("\n", ";").split(";") if p.strip()):
        bits = [b.strip() for b in part.split(",")]
        try:
            fraction, lane = float(bits[0]), int(bits[1])
            if len(bits) != 2:
                raise ValueError
        except (ValueError, IndexError):
            raise ServiceError(
                f"box {n + 1}: write each position as 'fraction,lane' (e.g. 0.25,1), "
                f"positions separated by ';'; got {part.strip()!r}",
                field="object_positions",
            ) from None
        positions.append([fraction, lane])
    return positions


def race_config(race_type: str, stored: dict[str, Any] | None) -> RaceConfig:
    """The :class:`RaceConfig` of a stored race (``race_type`` + ``race_config`` columns)."""
    if race_type == RaceType.TIME_TRIAL or not stored:
        return RaceConfig(race_type=race_type)
    return RaceConfig.from_dict({**stored, "race_type": race_type})


def check_race_type(race_type: str) -> None:
    """A race type the simulator can run."""
    if race_type not in RaceType.values or race_type not in SUPPORTED_RACE_TYPES:
        raise ServiceError(f"unknown race type {race_type!r}", field="race_type")


def sensor_advice(race_type: str, sensors: list[str] | tuple[str, ...]) -> str:
    """DeepRacer's guidance (deepracer-spec §4) when the sensors are weak for the race, or
    ``""``: a hint for the form, never a refusal."""
    lidar = any("LIDAR" in s for s in sensors)
    stereo = "STEREO_CAMERAS" in sensors
    if race_type == RaceType.HEAD_TO_BOT and not (stereo and lidar):
        return "DeepRacer recommends stereo cameras with a LIDAR to race against bot cars."
    if race_type == RaceType.OBJECT_AVOIDANCE and not (stereo or lidar):
        return (
            "A single camera does for fixed boxes; for boxes placed at random DeepRacer "
            "recommends stereo cameras or a LIDAR."
        )
    return ""


def _field_for(message: str) -> str:
    for word, field in _FIELD_OF_WORD:
        if word in message:
            return field
    return "race_type"
