"""The reward: DeepRacer's default function and the checks every returned value goes through."""

from __future__ import annotations

import math
from collections.abc import Callable

REWARD_LIMIT = 1e5
"""DeepRacer aborts a job whose reward leaves ±this range."""

RewardFunction = Callable[[dict], float]


class RewardValueError(ValueError):
    """The reward function returned something that is not a usable number."""


def progress_reward(params: dict) -> float:
    """The default reward: stay near the centre line, all wheels on the track."""
    if not params["all_wheels_on_track"] or params["is_offtrack"]:
        return 1e-3
    half = params["track_width"] / 2
    return float(max(1e-3, 1.0 - (params["distance_from_center"] / half) ** 2))


def judge_reward(reward_function: RewardFunction, params: dict) -> float:
    """``reward_function(params)`` as a float; :class:`RewardValueError` naming the step for
    anything else, NaN, ±inf or a value outside ±:data:`REWARD_LIMIT`."""
    value = reward_function(params)
    try:
        reward = float(value)
    except (TypeError, ValueError) as exc:
        raise RewardValueError(
            f"step {params['steps']}: the reward function returned {value!r}, not a number"
        ) from exc
    if not math.isfinite(reward) or abs(reward) > REWARD_LIMIT:
        raise RewardValueError(
            f"step {params['steps']}: the reward function returned {reward}, outside "
            f"[-{REWARD_LIMIT:g}, {REWARD_LIMIT:g}]"
        )
    return reward
