"""The presets: valid configurations a model can be created from, each labelled for what it is,
and the racing preset faster by construction than DeepRacer's defaults."""

from __future__ import annotations

import pytest

from racing.actions import DEFAULT_DISCRETE
from training.rewards.examples import EXAMPLES, example_source
from training.rl.hyperparams import defaults_for, parse_hyperparameters
from training.rl.metadata import build_metadata
from training.rl.presets import (
    DEEPRACER_DEFAULTS,
    PRESETS,
    RACING,
    UnknownPreset,
    preset,
)


@pytest.mark.parametrize("chosen", PRESETS, ids=[p.id for p in PRESETS])
def test_every_preset_is_a_valid_model_configuration(chosen) -> None:
    metadata = build_metadata(
        action_space=chosen.actions(),
        training_algorithm=chosen.algorithm,
        sensor=["FRONT_FACING_CAMERA"],
        neural_network=chosen.network,
    )
    assert metadata.action_space_type == "discrete"
    hp = chosen.hyperparameters.to_json()
    assert parse_hyperparameters(hp, chosen.algorithm).to_json() == hp
    assert chosen.reward_example in {e.id for e in EXAMPLES}
    assert "def reward_function(params)" in example_source(chosen.reward_example)
    assert chosen.label and len(chosen.summary) > 40


def test_deepracer_defaults_are_exactly_the_consoles_defaults() -> None:
    assert list(DEEPRACER_DEFAULTS.actions()) == list(DEFAULT_DISCRETE)
    assert DEEPRACER_DEFAULTS.hyperparameters == defaults_for("clipped_ppo")
    assert DEEPRACER_DEFAULTS.reward_example == "follow_center_line"


def test_the_racing_preset_drives_faster_and_looks_less_far_ahead() -> None:
    assert max(a["speed"] for a in RACING.actions()) == 3.0
    assert max(a["speed"] for a in DEEPRACER_DEFAULTS.actions()) == 1.0
    assert RACING.hyperparameters.discount_factor == 0.99
    assert RACING.reward_example == "speed_along_track"


def test_actions_are_a_fresh_copy() -> None:
    actions = RACING.actions()
    actions[0]["speed"] = 99.0
    assert RACING.actions()[0]["speed"] == 1.5


def test_an_unknown_preset_names_the_known_ones() -> None:
    assert preset("racing") is RACING
    with pytest.raises(UnknownPreset) as caught:
        preset("turbo")
    assert str(caught.value) == "unknown preset 'turbo': use one of deepracer_defaults, racing"
