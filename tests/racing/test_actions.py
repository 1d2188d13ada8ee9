"""Action spaces in model_metadata.json form."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

from racing.actions import (
    DEFAULT_DISCRETE,
    ActionSpaceError,
    ActionSpec,
    discrete_action_list,
)


def test_default_is_deepracers_ten_actions():
    spec = ActionSpec.parse(None)
    assert spec.kind == "discrete" and len(spec.actions) == 10
    assert spec.actions[0] == (-30.0, 0.5) and spec.actions[9] == (30.0, 1.0)
    assert isinstance(spec.gym_space, spaces.Discrete)
    assert spec.decode(np.int64(3)) == (-15.0, 1.0)


def test_generator_is_steering_major():
    actions = discrete_action_list(30, 5, 1.0, 2)
    assert [tuple(a.values()) for a in actions] == [
        (a["steering_angle"], a["speed"]) for a in DEFAULT_DISCRETE
    ]
    with pytest.raises(ActionSpaceError, match="2-30"):
        discrete_action_list(30, 7, 4, 5)


def test_continuous_ranges_and_clipping():
    spec = ActionSpec.parse(
        {"steering_angle": {"low": -20, "high": 20}, "speed": {"low": 0.5, "high": 4}}
    )
    assert isinstance(spec.gym_space, spaces.Box)
    assert spec.decode([10.0, 2.0]) == (10.0, 2.0)
    with pytest.raises(ActionSpaceError, match="outside"):
        spec.decode([25.0, 2.0])


@pytest.mark.parametrize(
    "definition, message",
    [
        ([{"steering_angle": 0, "speed": 1}], "2-30"),
        ([{"steering_angle": 0, "speed": 1}] * 31, "2-30"),
        ([{"steering_angle": 45, "speed": 1}, {"steering_angle": 0, "speed": 1}], "-30..30"),
        ([{"steering_angle": 0, "speed": 9}, {"steering_angle": 0, "speed": 1}], "0.1..4"),
        ([{"steering_angle": "x", "speed": 1}, {"steering_angle": 0, "speed": 1}], "number"),
        ([{"speed": 1}, {"steering_angle": 0, "speed": 1}], "needs"),
        (
            {"steering_angle": {"low": 10, "high": -10}, "speed": {"low": 1, "high": 2}},
            "low < high",
        ),
        ({"speed": {"low": 1, "high": 2}}, "continuous"),
        ("fast", "list"),
    ],
)
def test_bad_definitions_are_refused_clearly(definition, message):
    with pytest.raises(ActionSpaceError, match=message):
        ActionSpec.parse(definition)


@pytest.mark.parametrize("action", [10, -1, 2.5, "3", None, [1, 2], True])
def test_discrete_actions_outside_the_space(action):
    with pytest.raises(ActionSpaceError):
        ActionSpec.parse(None).decode(action)


def test_encode_picks_the_nearest_action():
    spec = ActionSpec.parse(None)
    assert spec.actions[spec.encode(14.0, 0.9)] == (15.0, 1.0)
    assert spec.to_metadata()[3] == {"steering_angle": -15.0, "speed": 1.0, "index": 3}
