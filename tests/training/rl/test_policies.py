"""The test-only tiny network (policies.TINY): it builds for every sensor layout with PPO and SAC
through the trainer's own builder, is far smaller than the lean default, and is never offered to
users (no form choice, no metadata, no match for an imported graph)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from training.rl.algorithms import build_model
from training.rl.hyperparams import parse_hyperparameters
from training.rl.metadata import MetadataError, ModelMetadata, build_metadata
from training.rl.policies import (
    COMPACT,
    DEEPRACER_NAMES,
    LEAN,
    NETWORK_LABELS,
    NETWORKS,
    SHALLOW,
    SPECS,
    TINY,
    CameraExtractor,
    CameraLidarExtractor,
)

DISCRETE = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2.0}}
SENSORS = {
    "mono": ["FRONT_FACING_CAMERA"],
    "stereo": ["STEREO_CAMERAS"],
    "camera-lidar": ["FRONT_FACING_CAMERA", "LIDAR"],
    "stereo-sector-lidar": ["STEREO_CAMERAS", "SECTOR_LIDAR"],
}


class SpacesEnv(gym.Env):
    """Random observations of the metadata's spaces: enough for SB3 to build and step."""

    def __init__(self, metadata: ModelMetadata) -> None:
        self.observation_space = metadata.observation_space
        self.action_space = metadata.actions.gym_space

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple:
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action) -> tuple:
        return self.observation_space.sample(), 1.0, False, False, {}


def build(algorithm: str, sensors: list[str], network: str):
    actions = CONTINUOUS if algorithm == "sac" else DISCRETE
    metadata = build_metadata(action_space=actions, training_algorithm=algorithm, sensor=sensors)
    env = DummyVecEnv([lambda: SpacesEnv(metadata)])
    hp = parse_hyperparameters({"batch_size": 32, "num_epochs": 3}, algorithm)
    return build_model(algorithm, env, hp, network=network, initial_steps=32)


def parameters(model) -> int:
    return sum(p.numel() for p in model.policy.parameters())


@pytest.mark.parametrize("algorithm", ["clipped_ppo", "sac"])
@pytest.mark.parametrize("sensors", SENSORS.values(), ids=SENSORS.keys())
def test_the_tiny_network_builds_drives_and_is_far_below_lean(algorithm, sensors):
    model = build(algorithm, sensors, TINY)
    extractor = model.policy.actor.features_extractor if algorithm == "sac" else (
        model.policy.features_extractor)  # fmt: skip
    lidar = len(sensors) > 1
    assert isinstance(extractor, CameraLidarExtractor if lidar else CameraExtractor)
    assert extractor.network == TINY
    # (C, 120, 160) pooled 8× to (C, 15, 20), 4 filters 3×3 stride 2: (4, 7, 9) -> 16 units;
    # a LIDAR adds its 16-unit embedder.
    camera = extractor.camera if lidar else extractor
    assert camera.linear[0].in_features == 4 * 7 * 9 and camera.features_dim == 16
    assert extractor.features_dim == (32 if lidar else 16)
    obs = model.env.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert model.env.action_space.contains(action[0])
    if algorithm == "clipped_ppo":
        model.learn(32)  # one rollout and one update through DeepRacerPPO
        assert model.num_timesteps == 32
    lean = build(algorithm, sensors, LEAN)
    assert parameters(lean) > 20 * parameters(model), (parameters(lean), parameters(model))


def test_the_tiny_extractor_takes_a_batch_of_images():
    space = gym.spaces.Box(0, 1, (2, 120, 160), np.float32)
    out = CameraExtractor(space, TINY)(torch.zeros(5, 2, 120, 160))
    assert out.shape == (5, 16)


def test_the_tiny_network_is_never_offered_to_users():
    """Not a choice of the form, not valid metadata (so no import or model row names it), no
    match for an imported DeepRacer graph; exported by mistake, it would say DeepRacer's
    shallow CNN."""
    assert TINY not in NETWORKS and TINY not in NETWORK_LABELS and TINY not in SPECS
    with pytest.raises(MetadataError, match="neural_network"):
        build_metadata(action_space=DISCRETE, neural_network=TINY)
    assert DEEPRACER_NAMES[TINY] == SHALLOW


def test_the_compact_network_is_offered_and_cheaper_than_lean() -> None:
    """Racecraft's compact network (the racing preset's): 4×4 averaging to 40×30, two
    convolutions of 16 filters, 128 units; a user's choice with valid metadata, exported under
    DeepRacer's shallow name, and under a third of the lean network's weights."""
    assert COMPACT in NETWORKS and "compact" in NETWORK_LABELS[COMPACT].lower()
    assert SPECS[COMPACT] == (4, [(16, 4, 2), (16, 4, 2)], 128)
    assert build_metadata(action_space=DISCRETE, neural_network=COMPACT).neural_network == COMPACT
    assert DEEPRACER_NAMES[COMPACT] == SHALLOW
    extractor = CameraExtractor(gym.spaces.Box(0, 1, (1, 120, 160), np.float32), COMPACT)
    # (1, 120, 160) -> (1, 30, 40) -> (16, 14, 19) -> (16, 6, 8) = 768 -> 128 units
    assert extractor.linear[0].in_features == 16 * 6 * 8 and extractor.features_dim == 128
    assert extractor(torch.zeros(3, 1, 120, 160)).shape == (3, 128)
    compact, lean = (
        build("clipped_ppo", SENSORS["mono"], COMPACT),
        build("clipped_ppo", SENSORS["mono"], LEAN),
    )
    assert 3 * parameters(compact) < parameters(lean), (parameters(compact), parameters(lean))
