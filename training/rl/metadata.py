"""``model_metadata.json``: DeepRacer's description of a model, parsed, validated and built.

Keys (deepracer-spec §2.3) and what happens when one is missing:

- ``action_space`` (required): a list of 2-30 ``{"steering_angle": deg, "speed": m/s}`` or
  ``{"steering_angle": {"low", "high"}, "speed": {"low", "high"}}``; checked by
  :meth:`racing.actions.ActionSpec.parse`.
- ``action_space_type``: ``discrete`` | ``continuous``; must match ``action_space``. When
  missing it is read from the shape of ``action_space`` (a list is DeepRacer's default,
  ``discrete``; a dict of ranges can only be ``continuous``).
- ``training_algorithm``: ``clipped_ppo`` (default) | ``sac``; SAC needs a continuous space.
- ``sensor``: exactly one camera, ``FRONT_FACING_CAMERA`` (default) or ``STEREO_CAMERAS``,
  optionally with one LIDAR: ``LIDAR``, ``SECTOR_LIDAR`` or ``DISCRETIZED_SECTOR_LIDAR``
  (deepracer-spec §4; stored camera first). DeepRacer's older names for the single camera,
  ``OBSERVATION`` and ``LEFT_CAMERA``, are read as ``FRONT_FACING_CAMERA``.
- ``neural_network``: one of :data:`training.rl.policies.NETWORKS` (DeepRacer's three CNNs and
  Racecraft's compact and lean CNNs); default ``DEEP_CONVOLUTIONAL_NETWORK_SHALLOW`` as in
  DeepRacer.
- ``version``: SimApp physics version, kept as the string given (a number is turned into its
  string); default ``"5"``.

Unknown keys (``lidar_config``, ``preprocess_type``, ...) are kept in ``extra`` and written
back unchanged. Every problem raises :class:`MetadataError` naming the key.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from racing.actions import ActionSpaceError, ActionSpec
from racing.lidar import LidarSensor
from racing.sensors import (
    SENSOR_CAMERA,
    SENSOR_STEREO,
    SensorError,
    validate_sensors,
)
from training.rl.policies import NETWORKS, SHALLOW

FILENAME = "model_metadata.json"
ACTION_SPACE_TYPES = ("discrete", "continuous")
ALGORITHMS = ("clipped_ppo", "sac")
DEFAULT_VERSION = "5"
DEFAULT_NETWORK = SHALLOW
SENSOR_ALIASES = {"OBSERVATION": SENSOR_CAMERA, "LEFT_CAMERA": SENSOR_CAMERA}
"""DeepRacer's older names of the single front camera (SimApp v1 models say ``observation``)."""
MAX_METADATA_BYTES = 1_000_000
KNOWN_KEYS = (
    "action_space",
    "action_space_type",
    "training_algorithm",
    "sensor",
    "neural_network",
    "version",
)


class MetadataError(ValueError):
    """A bad ``model_metadata.json``; ``field`` names the offending key."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


@dataclass(frozen=True)
class ModelMetadata:
    """A validated ``model_metadata.json``. Build one with :func:`build_metadata` or
    :meth:`from_json`; ``to_json()`` gives DeepRacer's dict back."""

    actions: ActionSpec
    training_algorithm: str = "clipped_ppo"
    sensor: tuple[str, ...] = (SENSOR_CAMERA,)
    neural_network: str = DEFAULT_NETWORK
    version: str = DEFAULT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def action_space_type(self) -> str:
        return self.actions.kind

    @property
    def camera(self) -> str:
        """``FRONT_FACING_CAMERA`` or ``STEREO_CAMERAS``."""
        return self.sensor[0]

    @property
    def channels(self) -> int:
        """Image channels the policy sees: 1 for the front camera, 2 for the stereo pair."""
        return 2 if self.camera == SENSOR_STEREO else 1

    @property
    def observation_shape(self) -> tuple[int, int, int]:
        """The policy's image input, channel-first: ``(C, 120, 160)``."""
        return (self.channels, 120, 160)

    @property
    def lidar(self) -> str | None:
        """The LIDAR sensor's id (``LIDAR``, ``SECTOR_LIDAR``, ``DISCRETIZED_SECTOR_LIDAR``) or
        None for a camera-only model."""
        return self.sensor[1] if len(self.sensor) > 1 else None

    @property
    def observation_space(self) -> gym.spaces.Space:
        """The simulator's observation space for these sensors (as :class:`racing.env.RacingEnv`
        builds it): the camera ``Box(0, 255, (120, 160, C), uint8)``, or with a LIDAR a ``Dict``
        keyed by the sensor ids."""
        image = gym.spaces.Box(0, 255, (120, 160, self.channels), np.uint8)
        if self.lidar is None:
            return image
        return gym.spaces.Dict({self.camera: image, self.lidar: LidarSensor(self.lidar).space})

    def to_json(self) -> dict[str, Any]:
        """DeepRacer's dict (``action_space`` with an ``index`` per discrete action)."""
        return {
            **self.extra,
            "action_space": self.actions.to_metadata(),
            "sensor": list(self.sensor),
            "neural_network": self.neural_network,
            "training_algorithm": self.training_algorithm,
            "action_space_type": self.action_space_type,
            "version": self.version,
        }

    def dumps(self) -> bytes:
        """``to_json()`` as the UTF-8 bytes of ``model_metadata.json`` (indented, stable)."""
        return (json.dumps(self.to_json(), indent=2, sort_keys=True) + "\n").encode()

    @classmethod
    def from_json(cls, data: Any) -> ModelMetadata:
        """Validate a decoded ``model_metadata.json`` dict. Raises :class:`MetadataError`."""
        if not isinstance(data, dict):
            raise MetadataError(FILENAME, "must be a JSON object")
        if "action_space" not in data:
            raise MetadataError("action_space", "is required")
        raw_space = data["action_space"]
        kind = data.get("action_space_type")
        if kind is None:
            kind = "continuous" if isinstance(raw_space, dict) else "discrete"
        return build_metadata(
            action_space=raw_space,
            action_space_type=kind,
            training_algorithm=data.get("training_algorithm", "clipped_ppo"),
            sensor=data.get("sensor", [SENSOR_CAMERA]),
            neural_network=data.get("neural_network", DEFAULT_NETWORK),
            version=data.get("version", DEFAULT_VERSION),
            extra={k: v for k, v in data.items() if k not in KNOWN_KEYS},
        )


def parse_metadata(raw: bytes | str) -> ModelMetadata:
    """Parse the text of a ``model_metadata.json`` file (UTF-8, at most 1 MB)."""
    if isinstance(raw, bytes):
        if len(raw) > MAX_METADATA_BYTES:
            raise MetadataError(FILENAME, f"is larger than {MAX_METADATA_BYTES} bytes")
        try:
            raw = raw.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise MetadataError(FILENAME, f"is not UTF-8 text ({exc.reason})") from None
    try:
        data = json.loads(raw.removeprefix("\ufeff"), parse_constant=_no_constant)
    except (json.JSONDecodeError, ValueError) as exc:
        raise MetadataError(FILENAME, f"is not valid JSON: {exc}") from None
    return ModelMetadata.from_json(data)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not allowed")


def build_metadata(
    *,
    action_space: list | tuple | dict,
    action_space_type: str | None = None,
    training_algorithm: str = "clipped_ppo",
    sensor: list[str] | tuple[str, ...] | str = (SENSOR_CAMERA,),
    neural_network: str = DEFAULT_NETWORK,
    version: str | int | float = DEFAULT_VERSION,
    extra: dict[str, Any] | None = None,
) -> ModelMetadata:
    """A validated :class:`ModelMetadata` from its parts (``action_space`` in DeepRacer's form
    or an :class:`ActionSpec`; ``action_space_type`` ``None`` = taken from ``action_space``).

    Names are matched case-insensitively and stored in DeepRacer's spelling. Raises
    :class:`MetadataError` naming the first bad key.
    """
    actions = _action_spec(action_space)
    kind = actions.kind
    if action_space_type is not None:
        kind = _choice("action_space_type", action_space_type, ACTION_SPACE_TYPES, lower=True)
    if kind != actions.kind:
        raise MetadataError(
            "action_space_type",
            f"says {kind} but action_space is {actions.kind} "
            f"({'a list of actions' if actions.kind == 'discrete' else 'a dict of ranges'})",
        )
    algorithm = _choice("training_algorithm", training_algorithm, ALGORITHMS, lower=True)
    if algorithm == "sac" and kind != "continuous":
        raise MetadataError(
            "training_algorithm",
            "SAC works only with a continuous action space: choose PPO or a continuous "
            "action space",
        )
    return ModelMetadata(
        actions=actions,
        training_algorithm=algorithm,
        sensor=_sensors(sensor),
        neural_network=_choice("neural_network", neural_network, NETWORKS, lower=False),
        version=_version(version),
        extra=dict(extra or {}),
    )


def _action_spec(value: Any) -> ActionSpec:
    if isinstance(value, ActionSpec):
        return value
    if value is None:
        raise MetadataError("action_space", "is required")
    try:
        return ActionSpec.parse(value)
    except ActionSpaceError as exc:
        raise MetadataError("action_space", str(exc)) from None


def _choice(key: str, value: Any, allowed: tuple[str, ...], *, lower: bool) -> str:
    if not isinstance(value, str):
        raise MetadataError(key, f"must be one of {', '.join(allowed)}; got {value!r}")
    text = value.strip().lower() if lower else value.strip().upper()
    if text not in allowed:
        raise MetadataError(key, f"must be one of {', '.join(allowed)}; got {value!r}")
    return text


def _sensors(value: Any) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list | tuple) or not all(isinstance(s, str) for s in value):
        raise MetadataError("sensor", "must be a list of sensor names")
    names = [SENSOR_ALIASES.get(s.strip().upper(), s.strip().upper()) for s in value]
    try:
        return validate_sensors(names)
    except SensorError as exc:
        raise MetadataError("sensor", str(exc)) from None


def _version(value: Any) -> str:
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise MetadataError("version", f'must be a version number like "5", not {value!r}')
    text = value.strip() if isinstance(value, str) else str(value)
    try:
        number = float(text)
    except ValueError:
        raise MetadataError(
            "version", f'must be a version number like "5", not {value!r}'
        ) from None
    if not math.isfinite(number) or not 1 <= number < 100 or len(text) > 16:
        raise MetadataError("version", f"must be a SimApp version (1 or more), not {value!r}")
    return text
