"""The race and sensor options of ``racecraft_create_model`` and ``racecraft_evaluate``: the
command-line twin of :mod:`console.race_form` (the wizard's and the evaluation form's race
fields).

The options only ask: each becomes one setting of :func:`training.services.race_settings`
(DeepRacer's race types, 1-6 boxes or bots, bot speed, fixed positions, lane changes) or one
sensor of :func:`training.services.model_create`, and the services say what is wrong. Their
:class:`~training.errors.ServiceError` becomes a :class:`CommandError` that names the option
(:func:`race_errors`), with the services' setting names replaced by the options that set them.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from django.core.management.base import CommandError

from racing.race import RaceConfig
from racing.sensors import SUPPORTED_SENSORS
from training import services
from training.management.cli import service_errors
from training.models import RaceType
from training.services import ServiceError

RACE_TYPE_CHOICES = [str(t).lower() for t in services.SUPPORTED_RACE_TYPES]
"""``time_trial``, ``object_avoidance``, ``head_to_bot`` (upper case accepted too)."""
_DEFAULTS = RaceConfig(**services.RACE_DEFAULTS)
"""A new race's settings where no option is given (the wizard's too)."""


@dataclass(frozen=True)
class RaceOption:
    """One command-line option and the race setting it sets."""

    flag: str
    setting: str
    help: str
    type: Any = None
    metavar: str | None = None
    switch: bool = False  # --x / --no-x


BOX_OPTIONS = (
    RaceOption("--boxes", "number_of_objects", type=int, metavar="N",
               help=f"number of boxes, 1-6 (default {_DEFAULTS.number_of_objects}; with "
               "--box-positions, one box per position)"),
    RaceOption("--box-positions", "object_positions", metavar="FRACTION:LANE",
               help="fixed boxes: fraction of the lap and lane (1 inner, -1 outer) of each box, "
               "e.g. 0.25:1 0.5:-1 (0.07-0.90, at least 0.13 apart; DeepRacer-for-Cloud's "
               "'0.25,1;0.5,-1' works too). Default: evenly spaced, lanes alternating"),
    RaceOption("--randomize-boxes", "randomize_objects", switch=True,
               help="move every box to a random place and lane each episode (default: fixed)"),
    RaceOption("--box-gap", "min_object_gap_m", type=float, metavar="METRES",
               help=f"least distance between boxes (default {_DEFAULTS.min_object_gap_m:g})"),
)  # fmt: skip
BOT_OPTIONS = (
    RaceOption("--bots", "number_of_bots", type=int, metavar="N",
               help=f"number of bot cars, 1-6 (default {_DEFAULTS.number_of_bots})"),
    RaceOption("--bot-speed", "bot_speed", type=float, metavar="M/S",
               help=f"bot cars' speed, 0.2-6 m/s (default {_DEFAULTS.bot_speed:g})"),
    RaceOption("--bot-lane-change", "bot_lane_change", switch=True,
               help="bot cars change lanes (default: they keep theirs)"),
    RaceOption("--lane-change-min", "lane_change_min_s", type=float, metavar="SECONDS",
               help=f"least wait before a lane change (default {_DEFAULTS.lane_change_min_s:g})"),
    RaceOption("--lane-change-max", "lane_change_max_s", type=float, metavar="SECONDS",
               help=f"longest wait before a lane change (default {_DEFAULTS.lane_change_max_s:g})"),
    RaceOption("--randomize-bots", "randomize_bots", switch=True,
               help="place the bot cars at random each episode (default: evenly spaced)"),
    RaceOption("--bot-gap", "min_bot_gap_m", type=float, metavar="METRES",
               help=f"least distance between bot cars (default {_DEFAULTS.min_bot_gap_m:g})"),
)  # fmt: skip
RACE_OPTIONS = BOX_OPTIONS + BOT_OPTIONS
FLAG_OF_FIELD = {
    "race_type": "--race-type",
    "sensors": "--sensor",
    **{o.setting: o.flag for o in RACE_OPTIONS},
}
"""The option behind each field a ServiceError names."""


def box_positions(text: str) -> list[list[float | int]]:
    """One ``--box-positions`` word: ``FRACTION:LANE`` (or DRfC's ``f,l;f,l``) as
    ``[[fraction, lane], ...]``; the ranges are the service's to check."""
    try:
        return services.parse_object_positions(text.replace(":", ","))
    except ServiceError:
        raise argparse.ArgumentTypeError(
            f"write each box as FRACTION:LANE, e.g. 0.25:1 (lane 1 inner, -1 outer); got {text!r}"
        ) from None


def sensor_names(text: str) -> list[str]:
    """One ``--sensor`` word: a sensor name or a comma list of them, upper-cased."""
    return [name.strip().upper() for name in text.split(",") if name.strip()]


def add_race_arguments(parser: argparse.ArgumentParser, *, evaluation: bool) -> None:
    """``--race-type`` and the box and bot options (two argument groups, listed in --help)."""
    parser.add_argument(
        "--race-type",
        type=str.lower,
        choices=RACE_TYPE_CHOICES,
        help=(
            "the race: boxes or bot cars on the track. Default: the model's own race and "
            "settings; the options below change them"
            if evaluation
            else "the race the model trains for (default: time_trial)"
        ),
    )
    groups = (
        ("object avoidance (--race-type object_avoidance)", BOX_OPTIONS),
        ("head-to-bot (--race-type head_to_bot)", BOT_OPTIONS),
    )
    for title, options in groups:
        group = parser.add_argument_group(title)
        for option in options:
            group.add_argument(option.flag, dest=option.setting, help=option.help,
                               **_argument_kind(option))  # fmt: skip


def _argument_kind(option: RaceOption) -> dict[str, Any]:
    if option.switch:
        return {"action": argparse.BooleanOptionalAction, "default": None}
    if option.setting == "object_positions":
        return {"type": box_positions, "nargs": "+", "metavar": option.metavar}
    return {"type": option.type, "metavar": option.metavar}


def add_sensor_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sensor",
        dest="sensor",
        type=sensor_names,
        action="append",
        metavar="SENSOR",
        help="the car's sensors, repeated or a comma list: one camera, optionally with one "
        f"LIDAR; one of {', '.join(SUPPORTED_SENSORS)} (e.g. --sensor STEREO_CAMERAS,LIDAR). "
        "Replaces the sensor of model_metadata.json or the preset (default: "
        "FRONT_FACING_CAMERA)",
    )


def given_sensors(options: dict[str, Any]) -> list[str] | None:
    """The ``--sensor`` names in the order given, or None without the option."""
    if not options.get("sensor"):
        return None
    return [name for names in options["sensor"] for name in names]


def given_settings(options: dict[str, Any]) -> dict[str, Any]:
    """The race settings the options give (only those given)."""
    settings = {}
    for option in RACE_OPTIONS:
        value = options.get(option.setting)
        if value is None:
            continue
        if option.setting == "object_positions":
            value = [position for word in value for position in word]
        settings[option.setting] = value
    return settings


def race_type_option(options: dict[str, Any]) -> str | None:
    """``--race-type`` as the services spell it (``HEAD_TO_BOT``), or None."""
    return options["race_type"].upper() if options.get("race_type") else None


def evaluation_race(
    options: dict[str, Any], model_race_type: str, model_race: dict[str, Any] | None
) -> tuple[str | None, dict[str, Any] | None]:
    """``(race_type, race_config)`` for :func:`training.services.evaluation_start`, as the
    evaluation form fills them: nothing given is ``(None, None)``, the model's own race; a race
    setting without ``--race-type`` changes the model's race. In the model's own race type the
    options change its stored settings (the form shows them filled in); in another, they start
    from the defaults. A new box count or new positions replace both stored ones."""
    race_type = race_type_option(options)
    settings = given_settings(options)
    if race_type is None and not settings:
        return None, None
    race_type = race_type or model_race_type
    base: dict[str, Any] = {}
    if race_type == model_race_type and race_type != RaceType.TIME_TRIAL:
        base = {k: v for k, v in (model_race or {}).items() if k != "race_type"}
        if {"number_of_objects", "object_positions"} & set(settings):
            base.pop("number_of_objects", None)
            base.pop("object_positions", None)
    return race_type, {**base, **settings}


def _in_options(message: str) -> str:
    """The message with the services' setting names replaced by their options."""
    for option in RACE_OPTIONS:
        message = re.sub(rf"'?\b{option.setting}\b'?", option.flag, message)
    return message


@contextmanager
def race_errors(options: dict[str, Any]) -> Iterator[None]:
    """:func:`~training.management.cli.service_errors`, naming the option of a race or sensor
    setting the service refused (``--bot-speed: --bot-speed must be 0.2-6.0 m/s...``). A
    sensor read from model_metadata.json is not the option's: its error keeps its words."""
    with service_errors():
        try:
            yield
        except ServiceError as exc:
            flag = FLAG_OF_FIELD.get(exc.field or "")
            if flag is None or (flag == "--sensor" and not options.get("sensor")):
                raise
            raise CommandError(f"{flag}: {_in_options(exc.message)}") from None


def race_summary(race_type: str, race: dict[str, Any] | None) -> str:
    """``time trial``, ``object avoidance (3 boxes, random)``, ``head-to-bot (2 bots at
    0.5 m/s, changing lanes)``: the race a command reports."""
    race = race or {}
    if race_type == RaceType.OBJECT_AVOIDANCE:
        boxes = race.get("number_of_objects", _DEFAULTS.number_of_objects)
        how = "random" if race.get("randomize_objects") else "fixed"
        return f"object avoidance ({boxes} box{'es' if boxes != 1 else ''}, {how})"
    if race_type == RaceType.HEAD_TO_BOT:
        bots = race.get("number_of_bots", _DEFAULTS.number_of_bots)
        speed = race.get("bot_speed", _DEFAULTS.bot_speed)
        lanes = ", changing lanes" if race.get("bot_lane_change") else ""
        return f"head-to-bot ({bots} bot{'s' if bots != 1 else ''} at {speed:g} m/s{lanes})"
    return "time trial"
