"""`manage.py racecraft_create_model`: a model from DeepRacer's files."""

from __future__ import annotations

import json
from argparse import ArgumentParser
from pathlib import Path
from typing import Any

from django.core.management.base import BaseCommand, CommandError

from training import services
from training.management.cli import (
    action_summary,
    add_owner_argument,
    add_track_argument,
)
from training.management.race_options import (
    add_race_arguments,
    add_sensor_argument,
    given_sensors,
    given_settings,
    race_errors,
    race_summary,
    race_type_option,
)
from training.models import Direction, RaceType
from training.rewards.examples import example_source
from training.rl.metadata import MetadataError, ModelMetadata, build_metadata, parse_metadata
from training.rl.presets import PRESETS, Preset, preset
from training.selectors import user_by_username
from training.services import conditions as services_conditions


def read_bytes(path: str, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise CommandError(f"cannot read the {what} {path}: {exc.strerror or exc}") from None


def read_text(path: str, what: str) -> str:
    try:
        return read_bytes(path, what).decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CommandError(f"the {what} {path} is not UTF-8 text ({exc.reason})") from None


def track_and_direction(text: str) -> tuple[str, str]:
    """``TRACK`` or ``TRACK:DIRECTION`` (native, ccw or cw) from ``--also-train-on``."""
    track, _, direction = text.partition(":")
    direction = direction or Direction.NATIVE
    if not track or direction not in Direction.values:
        raise CommandError(
            f"--also-train-on {text!r}: give TRACK or TRACK:DIRECTION, the direction one of "
            f"{', '.join(Direction.values)}"
        )
    return track, direction


def condition_range(text: str) -> tuple[str, tuple[float, float]]:
    """``FAMILY.PARAMETER=LOW:HIGH`` (or ``=VALUE``) from ``--condition``."""
    key, sep, value = text.partition("=")
    low, colon, high = value.partition(":")
    try:
        if not sep or not key.strip() or "." not in key:
            raise ValueError
        bounds = (float(low), float(high if colon else low))
    except ValueError:
        raise CommandError(
            f"--condition {text!r}: give FAMILY.PARAMETER=LOW:HIGH, e.g. light.brightness=-20:20"
        ) from None
    return key.strip(), bounds


RAMP_DEFAULT = services_conditions.RECOMMENDED_RAMP_EPISODES


def given_conditions(options: dict) -> dict:
    """The outside-world setting from ``--conditions`` and ``--condition`` ({}: off)."""
    families = [f for f in (options.get("conditions") or "").split(",") if f.strip()]
    ranges = dict(condition_range(text) for text in options.get("condition") or ())
    try:
        return services_conditions.conditions_build(
            families, ranges, ramp_episodes=options.get("conditions_ramp", RAMP_DEFAULT)
        )
    except services.ServiceError as exc:
        raise CommandError(f"--conditions: {exc.message}") from None


def preset_metadata(chosen: Preset) -> ModelMetadata:
    return build_metadata(
        action_space=chosen.actions(),
        training_algorithm=chosen.algorithm,
        sensor=["FRONT_FACING_CAMERA"],
        neural_network=chosen.network,
    )


def read_hyperparameters(path: str) -> dict:
    try:
        data = json.loads(read_text(path, "hyperparameters file"))
    except json.JSONDecodeError as exc:
        raise CommandError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise CommandError(f"{path} must hold a JSON object of hyperparameters")
    return data


EXAMPLE_METADATA = """\
Example model_metadata.json (DeepRacer's format; a discrete action space of 3 actions):

  {
    "action_space": [
      {"steering_angle": -30, "speed": 1.0},
      {"steering_angle": 0, "speed": 1.5},
      {"steering_angle": 30, "speed": 1.0}
    ],
    "sensor": ["FRONT_FACING_CAMERA"],
    "neural_network": "RACECRAFT_LEAN_CNN",
    "training_algorithm": "clipped_ppo",
    "action_space_type": "discrete",
    "version": "5"
  }

A continuous action space instead (PPO or "sac"):
    "action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2}},
    "action_space_type": "continuous"

Networks: RACECRAFT_COMPACT_CNN (fastest on a CPU), RACECRAFT_LEAN_CNN (fast on a CPU),
DEEP_CONVOLUTIONAL_NETWORK_SHALLOW (DeepRacer's 3-layer CNN), DEEP_CONVOLUTIONAL_NETWORK
(5 layers), DEEP_CONVOLUTIONAL_NETWORK_DEEP.
"""


class Command(BaseCommand):
    help = (
        "Create a model from DeepRacer's files: reward_function.py, model_metadata.json (action "
        "space, sensor, algorithm, network) and optionally hyperparameters.json, or from a "
        "preset (--preset racing: fast laps soon; deepracer_defaults), whose parts any of "
        "those files replace. --also-train-on trains one model on several tracks at once. The "
        "reward function is checked in the sandbox first, on every track. --race-type with "
        "its box or bot options and --sensor make object-avoidance and head-to-bot models, "
        "as the console's wizard does. Prints the new model's id (only the id with -v 0)."
    )

    def create_parser(self, prog_name: str, subcommand: str, **kwargs: Any):
        from argparse import RawDescriptionHelpFormatter

        parser = super().create_parser(prog_name, subcommand, **kwargs)
        parser.epilog = EXAMPLE_METADATA
        parser.formatter_class = RawDescriptionHelpFormatter
        return parser

    def add_arguments(self, parser: ArgumentParser) -> None:
        add_owner_argument(parser, required=True)
        parser.add_argument("--name", required=True, help="1-64 letters, digits or hyphens")
        parser.add_argument(
            "--preset",
            choices=[p.id for p in PRESETS],
            help="start from a preset: "
            + "; ".join(f"{p.id}: {p.label}" for p in PRESETS)
            + " (its action space, example reward and hyperparameters)",
        )
        parser.add_argument(
            "--reward", metavar="PATH", help="reward_function.py (required without --preset)"
        )
        parser.add_argument(
            "--metadata", metavar="PATH", help="model_metadata.json (required without --preset)"
        )
        parser.add_argument(
            "--hyperparameters",
            metavar="PATH",
            help="hyperparameters.json (default: the console's defaults for the algorithm)",
        )
        add_track_argument(parser, default="racecraft_summit")
        parser.add_argument(
            "--direction",
            choices=Direction.values,
            default=Direction.NATIVE,
            help="driving direction on the track (default: native)",
        )
        parser.add_argument(
            "--also-train-on",
            nargs="+",
            default=[],
            metavar="TRACK[:DIRECTION]",
            help="multi-track training: more tracks the model trains on at once, the cars "
            "dealt the tracks in turn (direction native, ccw or cw; default native)",
        )
        parser.add_argument(
            "--minutes",
            type=int,
            default=10,
            help="stop condition: minutes of training (1-1440, default 10)",
        )
        parser.add_argument(
            "--stop-when-ready",
            type=int,
            default=0,
            metavar="N",
            help="stop condition beside the minutes: stop once N evaluations in a row complete "
            "every lap, keeping the checkpoint that completed them (1-20; default 0, off)",
        )
        parser.add_argument("--description", default="", help="at most 255 characters")
        parser.add_argument(
            "--seed", type=int, default=None, help="random seed (default: a random one)"
        )
        add_sensor_argument(parser)
        add_race_arguments(parser, evaluation=False)
        parser.add_argument(
            "--conditions",
            metavar="FAMILY[,FAMILY...]",
            help="training for the world outside (off by default): each training episode "
            "draws its conditions from these families, each parameter over its training range: "
            "light, look, camera, car, latency (e.g. --conditions light,camera)",
        )
        parser.add_argument(
            "--condition",
            action="append",
            default=[],
            metavar="FAMILY.PARAMETER=LOW:HIGH",
            help="set one parameter's range of a family turned on with --conditions, anywhere "
            "within its widest (repeatable), e.g. --condition light.brightness=-20:20",
        )
        parser.add_argument(
            "--conditions-ramp",
            type=int,
            default=RAMP_DEFAULT,
            metavar="EPISODES",
            help="ease the conditions in over each car's first EPISODES training episodes, "
            f"from the clean world to their whole ranges (default {RAMP_DEFAULT}, the "
            "recommended curriculum; 0: the whole ranges from the first)",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        chosen = preset(options["preset"]) if options["preset"] else None
        if chosen is None and not (options["reward"] and options["metadata"]):
            raise CommandError("give --reward and --metadata, or --preset")
        if options["reward"]:
            reward = read_text(options["reward"], "reward function")
        else:
            reward = example_source(chosen.reward_example)
        if options["metadata"]:
            try:
                metadata = parse_metadata(read_bytes(options["metadata"], "metadata file"))
            except MetadataError as exc:
                raise CommandError(f"{options['metadata']}: {exc}") from None
        else:
            metadata = preset_metadata(chosen)
        hyperparameters = (
            read_hyperparameters(options["hyperparameters"]) if options["hyperparameters"] else None
        )
        if hyperparameters is None and chosen is not None:
            hyperparameters = chosen.hyperparameters.to_json()
        extra_tracks = [track_and_direction(t) for t in options["also_train_on"]]
        race_type = race_type_option(options) or RaceType.TIME_TRIAL
        conditions = given_conditions(options)
        with race_errors(options):
            owner = user_by_username(username=options["owner"])
            model = services.model_create(
                owner=owner,
                name=options["name"],
                description=options["description"],
                track_id=options["track"],
                direction=options["direction"],
                extra_tracks=extra_tracks,
                race_type=race_type,
                race_config=given_settings(options),
                sensors=given_sensors(options) or list(metadata.sensor),
                action_space=metadata.actions.to_metadata(),
                algorithm=metadata.training_algorithm,
                neural_network=metadata.neural_network,
                hyperparameters=hyperparameters,
                reward_function=reward,
                max_minutes=options["minutes"],
                stop_when_ready=options["stop_when_ready"],
                seed=options["seed"],
                conditions=conditions,
            )
        if options["verbosity"] == 0:
            self.stdout.write(str(model.pk))
            return
        families = services_conditions.conditions_families(model.conditions)
        world = f", outside world: {', '.join(families)}" if families else ""
        self.stdout.write(
            f"Created model {model.pk}: {model.name} ({model.algorithm}, {action_summary(model)}, "
            f"{', '.join(model.sensors)}, {model.neural_network}) on "
            f"{' + '.join(f'{t} ({d})' for t, d in model.training_tracks)}, "
            f"{race_summary(model.race_type, model.race_config)}, "
            f"stop: {model.stop_condition}{world}"
        )
        advice = services.sensor_advice(model.race_type, model.sensors)
        if advice:
            self.stdout.write(f"Note: {advice}")
        self.stdout.write(f"Train it with: manage.py racecraft_train {model.pk}")
