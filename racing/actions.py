"""Action spaces in DeepRacer's ``model_metadata.json`` form, turned into Gymnasium spaces.

Discrete: a list of ``{"steering_angle": deg, "speed": m/s}`` (2 to 30 of them; an ``index``
key is allowed and ignored). Continuous: ``{"steering_angle": {"low", "high"}, "speed":
{"low", "high"}}``. Steering is in degrees, positive = left; speed in m/s. Executed values are
clipped to ±30° and 0.1-4 m/s, as in DeepRacer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

MAX_STEERING_DEG = 30.0
MIN_SPEED = 0.1
MAX_SPEED = 4.0
MIN_DISCRETE_ACTIONS = 2
MAX_DISCRETE_ACTIONS = 30

DEFAULT_DISCRETE = tuple(
    {"steering_angle": steer, "speed": speed}
    for steer in (-30.0, -15.0, 0.0, 15.0, 30.0)
    for speed in (0.5, 1.0)
)
"""DeepRacer's default discrete space (DeepRacer on AWS): 5 steering × 2 speed levels."""

DEFAULT_CONTINUOUS = {
    "steering_angle": {"low": -30.0, "high": 30.0},
    "speed": {"low": 1.0, "high": 2.0},
}


class ActionSpaceError(ValueError):
    """An action-space definition or an action that does not fit it."""


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ActionSpaceError(f"{what} must be a number, not {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ActionSpaceError(f"{what} must be finite, not {value}")
    return value


def action_range_error(steering_deg: float, speed: float) -> str:
    """What is wrong with one discrete action's values ("" when nothing is)."""
    if abs(steering_deg) > MAX_STEERING_DEG:
        return f"steering angle {steering_deg:g} is outside -30..30 degrees"
    if not MIN_SPEED <= speed <= MAX_SPEED:
        return f"speed {speed:g} is outside 0.1..4 m/s"
    return ""


def discrete_action_list(
    max_steering: float, steering_levels: int, max_speed: float, speed_levels: int
) -> list[dict]:
    """DeepRacer's generator: steering evenly over ±max, speeds max·i/n, steering-major."""
    if not 1 <= max_steering <= MAX_STEERING_DEG:
        raise ActionSpaceError("max steering must be 1-30 degrees")
    if not MIN_SPEED <= max_speed <= MAX_SPEED:
        raise ActionSpaceError("max speed must be 0.1-4 m/s")
    if steering_levels < 1 or speed_levels < 1:
        raise ActionSpaceError("levels must be at least 1")
    steers = (
        [0.0]
        if steering_levels == 1
        else list(np.linspace(-max_steering, max_steering, steering_levels))
    )
    speeds = [max_speed * i / speed_levels for i in range(1, speed_levels + 1)]
    actions = [
        {"steering_angle": round(float(a), 4), "speed": round(float(v), 4)}
        for a in steers
        for v in speeds
    ]
    if not MIN_DISCRETE_ACTIONS <= len(actions) <= MAX_DISCRETE_ACTIONS:
        raise ActionSpaceError(
            f"that makes {len(actions)} actions; DeepRacer allows "
            f"{MIN_DISCRETE_ACTIONS}-{MAX_DISCRETE_ACTIONS}"
        )
    return actions


@dataclass(frozen=True)
class ActionSpec:
    """A parsed action space: ``kind`` is ``'discrete'`` or ``'continuous'``."""

    kind: str
    actions: tuple[tuple[float, float], ...] = ()
    steering_range: tuple[float, float] = (-MAX_STEERING_DEG, MAX_STEERING_DEG)
    speed_range: tuple[float, float] = (MIN_SPEED, MAX_SPEED)

    @classmethod
    def parse(cls, definition: list | tuple | dict | None) -> ActionSpec:
        """Read a ``model_metadata.json`` ``action_space`` value (None = DeepRacer's default)."""
        if definition is None:
            definition = DEFAULT_DISCRETE
        if isinstance(definition, dict):
            return cls._parse_continuous(definition)
        if not isinstance(definition, list | tuple):
            raise ActionSpaceError("action_space must be a list of actions or a dict of ranges")
        n = len(definition)
        if not MIN_DISCRETE_ACTIONS <= n <= MAX_DISCRETE_ACTIONS:
            raise ActionSpaceError(
                f"a discrete action space has {MIN_DISCRETE_ACTIONS}-{MAX_DISCRETE_ACTIONS} "
                f"actions; got {n}"
            )
        actions = []
        for i, item in enumerate(definition):
            if not isinstance(item, dict) or "steering_angle" not in item or "speed" not in item:
                raise ActionSpaceError(f"action {i} needs 'steering_angle' and 'speed'")
            steer = _number(item["steering_angle"], f"action {i} steering_angle")
            speed = _number(item["speed"], f"action {i} speed")
            error = action_range_error(steer, speed)
            if error:
                raise ActionSpaceError(f"action {i}: {error}")
            actions.append((steer, speed))
        return cls(kind="discrete", actions=tuple(actions))

    @classmethod
    def _parse_continuous(cls, definition: dict) -> ActionSpec:
        try:
            s_lo = _number(definition["steering_angle"]["low"], "steering_angle low")
            s_hi = _number(definition["steering_angle"]["high"], "steering_angle high")
            v_lo = _number(definition["speed"]["low"], "speed low")
            v_hi = _number(definition["speed"]["high"], "speed high")
        except (KeyError, TypeError) as exc:
            raise ActionSpaceError(
                "a continuous action space needs steering_angle {low, high} and speed {low, high}"
            ) from exc
        if not -MAX_STEERING_DEG <= s_lo < s_hi <= MAX_STEERING_DEG:
            raise ActionSpaceError("steering range must satisfy -30 <= low < high <= 30")
        if not MIN_SPEED <= v_lo < v_hi <= MAX_SPEED:
            raise ActionSpaceError("speed range must satisfy 0.1 <= low < high <= 4")
        return cls(kind="continuous", steering_range=(s_lo, s_hi), speed_range=(v_lo, v_hi))

    @property
    def gym_space(self) -> spaces.Space:
        if self.kind == "discrete":
            return spaces.Discrete(len(self.actions))
        low = np.array([self.steering_range[0], self.speed_range[0]], dtype=np.float32)
        high = np.array([self.steering_range[1], self.speed_range[1]], dtype=np.float32)
        return spaces.Box(low, high, dtype=np.float32)

    def decode(self, action) -> tuple[float, float]:
        """An action from the Gymnasium space to ``(steering_deg, speed)``, clipped as DeepRacer.

        Raises :class:`ActionSpaceError` for an action outside the space.
        """
        if self.kind == "discrete":
            value = action.item() if isinstance(action, np.ndarray) and action.size == 1 else action
            if isinstance(value, np.integer):
                value = int(value)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ActionSpaceError(f"a discrete action is an integer index, not {action!r}")
            index = value
            if not 0 <= index < len(self.actions):
                raise ActionSpaceError(
                    f"action {index} is outside the discrete space of {len(self.actions)} actions"
                )
            steer, speed = self.actions[index]
        else:
            arr = np.asarray(action, dtype=np.float64).reshape(-1)
            if arr.shape != (2,) or not np.all(np.isfinite(arr)):
                raise ActionSpaceError(
                    f"a continuous action is [steering_angle, speed], not {action!r}"
                )
            steer, speed = float(arr[0]), float(arr[1])
            tol = 1e-4
            if not (self.steering_range[0] - tol <= steer <= self.steering_range[1] + tol) or not (
                self.speed_range[0] - tol <= speed <= self.speed_range[1] + tol
            ):
                raise ActionSpaceError(
                    f"action [{steer:.3f}, {speed:.3f}] is outside steering "
                    f"{self.steering_range} × speed {self.speed_range}"
                )
        steer = min(MAX_STEERING_DEG, max(-MAX_STEERING_DEG, steer))
        speed = min(MAX_SPEED, max(MIN_SPEED, speed))
        return steer, speed

    def encode(self, steering: float, speed: float):
        """The action nearest to ``(steering, speed)``: an index, or a clipped float32 pair."""
        if self.kind == "discrete":
            acts = np.asarray(self.actions)
            cost = ((acts[:, 0] - steering) / 30.0) ** 2 + ((acts[:, 1] - speed) / 2.0) ** 2
            return int(np.argmin(cost))
        return np.array(
            [
                min(max(steering, self.steering_range[0]), self.steering_range[1]),
                min(max(speed, self.speed_range[0]), self.speed_range[1]),
            ],
            dtype=np.float32,
        )

    def to_metadata(self) -> list[dict] | dict:
        if self.kind == "discrete":
            return [
                {"steering_angle": s, "speed": v, "index": i}
                for i, (s, v) in enumerate(self.actions)
            ]
        return {
            "steering_angle": {"low": self.steering_range[0], "high": self.steering_range[1]},
            "speed": {"low": self.speed_range[0], "high": self.speed_range[1]},
        }
