"""The presets: valid configurations a model can be created from, each labelled for what it is,
and the racing preset faster by construction than DeepRacer's defaults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racing.actions import DEFAULT_DISCRETE
from racing.car import FRICTION, GRAVITY, MAX_SPEED, WHEELBASE_M
from racing.trackgen import min_radius
from racing.tracks import TrackCatalog
from training.rewards.examples import EXAMPLES, example_source
from training.rl.hyperparams import defaults_for, parse_hyperparameters
from training.rl.metadata import build_metadata
from training.rl.policies import COMPACT, LEAN
from training.rl.presets import (
    DEEPRACER_DEFAULTS,
    PRESETS,
    RACING,
    STRAIGHT_TOP_SPEED,
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
    assert max(a["speed"] for a in RACING.actions()) == STRAIGHT_TOP_SPEED == 3.5
    assert max(a["speed"] for a in DEEPRACER_DEFAULTS.actions()) == 1.0
    assert RACING.hyperparameters.discount_factor == 0.98
    assert RACING.hyperparameters.batch_size == 32  # twice the gradient steps: steadier seeds
    assert RACING.reward_example == "speed_along_track"


def test_the_racing_preset_trains_the_compact_network_and_the_defaults_the_lean_one() -> None:
    """The racing preset's network is the cheapest to update (docs/benchmarks.md, "The compact
    network"); DeepRacer's defaults keep the network they had, so their figures stay comparable."""
    assert RACING.network == COMPACT
    assert DEEPRACER_DEFAULTS.network == LEAN


def test_actions_are_a_fresh_copy() -> None:
    actions = RACING.actions()
    first = actions[0]["speed"]
    actions[0]["speed"] = 99.0
    assert RACING.actions()[0]["speed"] == first != 99.0


def test_every_racing_action_is_one_the_tyres_hold() -> None:
    """Lateral acceleration v² tan(angle) / wheelbase within the simulated grip (μg); straight
    ahead, the preset's top speed (docs/benchmarks.md, "Why seeds stall": not DeepRacer's 4 m/s)."""
    grip = FRICTION * GRAVITY
    for action in RACING.actions():
        v, angle = action["speed"], math.radians(abs(action["steering_angle"]))
        assert v**2 * math.tan(angle) / WHEELBASE_M <= grip, action
    # ... and each angle's fastest speed is the fastest that holds, within 0.5 m/s.
    fastest: dict[float, float] = {}
    for action in RACING.actions():
        angle = abs(action["steering_angle"])
        fastest[angle] = max(fastest.get(angle, 0.0), action["speed"])
    for angle, v in fastest.items():
        lateral = (v + 0.5) ** 2 * math.tan(math.radians(angle)) / WHEELBASE_M
        assert lateral > grip or (angle == 0.0 and v == STRAIGHT_TOP_SPEED < MAX_SPEED), (angle, v)
    angles = sorted({a["steering_angle"] for a in RACING.actions()})
    assert angles == [-20.0, -10.0, 0.0, 10.0, 20.0]  # symmetric


def test_an_unknown_preset_names_the_known_ones() -> None:
    assert preset("racing") is RACING
    with pytest.raises(UnknownPreset) as caught:
        preset("turbo")
    assert str(caught.value) == "unknown preset 'turbo': use one of deepracer_defaults, racing"


def test_the_racing_presets_sharpest_turn_fits_every_built_in_tracks_tightest_bend() -> None:
    """Without 30° the tightest circle the car can drive is 20°'s (0.45 m): it fits the tightest
    bend of every built-in track (docs/benchmarks.md, "Faster laps"), the car using the track's
    width. DeepRacer's tracks, built in since issue 49, have centre lines that bend tighter than
    that (re:Invent 2018 0.43 m, Tokyo's training track 0.33 m), so the circle is held to the
    bend's centre-line radius plus half the track's width: the widest line through it."""
    sharpest = max(abs(a["steering_angle"]) for a in RACING.actions())
    circle = WHEELBASE_M / math.tan(math.radians(sharpest))
    catalog = TrackCatalog()
    assert len(catalog.ids()) > 3  # Racecraft's and DeepRacer's
    for track_id in catalog.ids():
        track = catalog.load(track_id)
        assert circle < min_radius(np.array(track.waypoints)) + track.width / 2, track_id


def _racing_reward(speed: float, heading: float = 0.0, *, on_track: bool = True) -> float:
    namespace: dict = {}
    exec(compile(example_source(RACING.reward_example), "reward", "exec"), namespace)  # ours
    return namespace["reward_function"](
        {
            "is_offtrack": not on_track,
            "all_wheels_on_track": on_track,
            "waypoints": [(0.0, 0.0), (1.0, 0.0)],
            "closest_waypoints": [0, 1],
            "heading": heading,
            "speed": speed,
        }
    )


def test_the_racing_reward_pays_a_metre_more_the_faster_the_car_covers_it() -> None:
    """A step's reward times the steps a metre takes (1 / speed): the racing reward pays
    the speed squared, so a metre at 4 m/s earns twice a metre at 2 m/s; the speed itself
    would pay every metre the same."""
    per_metre = {v: _racing_reward(v) / v for v in (1.0, 2.0, 4.0)}
    assert per_metre[4.0] == pytest.approx(2 * per_metre[2.0]) == pytest.approx(4 * per_metre[1.0])
    assert _racing_reward(4.0) == pytest.approx(4.0)  # DeepRacer's top speed: 4, as before
    assert _racing_reward(4.0, heading=60.0) == pytest.approx(1.0)  # half of it along the track
    # Backwards, sideways or off the track earns (almost) nothing, however fast.
    assert _racing_reward(4.0, heading=180.0) == _racing_reward(4.0, heading=90.0) == 1e-3
    assert _racing_reward(4.0, on_track=False) == 1e-3
