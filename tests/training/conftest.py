"""Tiny real models for the export and import tests (trained once per session, on request)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm

from racing.env import RacingEnv
from training.rl.metadata import ModelMetadata, build_metadata
from training.rl.policies import policy_kwargs, sac_policy_kwargs

TRACK = "racecraft_summit"
CONTINUOUS = {"steering_angle": {"low": -25.0, "high": 20.0}, "speed": {"low": 0.5, "high": 3.0}}


@dataclass(frozen=True)
class TinyModel:
    model: BaseAlgorithm
    metadata: ModelMetadata


def tiny_ppo(env: RacingEnv, seed: int) -> PPO:
    """A PPO with the lean network after one 64-step update on ``env`` (closed after)."""
    model = PPO(
        "CnnPolicy",
        env,
        policy_kwargs=policy_kwargs(),
        n_steps=64,
        batch_size=32,
        n_epochs=1,
        device="cpu",
        seed=seed,
    )
    model.learn(64)
    env.close()
    return model


@pytest.fixture(scope="session")
def ppo_discrete() -> TinyModel:
    env = RacingEnv(TRACK)
    model = tiny_ppo(env, seed=1)
    meta = build_metadata(
        action_space=env.actions.to_metadata(), neural_network="RACECRAFT_LEAN_CNN"
    )
    return TinyModel(model, meta)


@pytest.fixture(scope="session")
def ppo_continuous() -> TinyModel:
    model = tiny_ppo(RacingEnv(TRACK, action_space=CONTINUOUS), seed=2)
    return TinyModel(
        model, build_metadata(action_space=CONTINUOUS, neural_network="RACECRAFT_LEAN_CNN")
    )


@pytest.fixture(scope="session")
def sac_continuous() -> TinyModel:
    env = RacingEnv(TRACK, action_space=CONTINUOUS)
    model = SAC(
        "CnnPolicy",
        env,
        policy_kwargs=sac_policy_kwargs(),
        buffer_size=1000,
        learning_starts=10,
        batch_size=16,
        device="cpu",
        seed=3,
    )
    model.learn(20)
    env.close()
    meta = build_metadata(
        action_space=CONTINUOUS, training_algorithm="sac", neural_network="RACECRAFT_LEAN_CNN"
    )
    return TinyModel(model, meta)


@pytest.fixture(scope="session")
def camera_frames() -> np.ndarray:
    """20 real front-camera observations, ``(20, 120, 160, 1)`` uint8, from random driving."""
    env = RacingEnv(TRACK)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    frames = []
    while len(frames) < 20:
        frames.append(obs)
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    return np.stack(frames)


@pytest.fixture
def ida_model(ppo_discrete, store_dir, db):
    """Makes Ida's model on the oval (``model_create`` keywords override) with
    ``ppo_discrete``'s checkpoint stored as its best, as a finished training leaves it."""
    from django.contrib.auth import get_user_model

    from training import services
    from training.interchange.export import checkpoint_bytes
    from training.store import get_store, keys_for

    def make(**overrides):
        owner = get_user_model().objects.create_user("ida", password="x-long-pass-1")
        kwargs = dict(owner=owner, name="oval", track_id="racecraft_oval",
                      action_space=ppo_discrete.metadata.actions.to_metadata(),
                      reward_function="def reward_function(params):\n    return 1.0\n",
                      seed=4242, validate_reward=False)  # fmt: skip
        model = services.model_create(**{**kwargs, **overrides})
        get_store().put_bytes(keys_for(model.pk).best, checkpoint_bytes(ppo_discrete.model))
        services.model_mark_checkpoint(model=model)
        return model

    return make


@pytest.fixture
def racer_model(store_dir, db):
    """Makes a model of a new user's on the oval with an (untrained) checkpoint stored as its
    best; ``trained=False`` leaves it without one."""
    import torch
    from django.contrib.auth import get_user_model

    from training import services
    from training.interchange.export import checkpoint_bytes
    from training.rl.checkpoints import new_model
    from training.store import get_store, keys_for

    def make(username: str, action_space: list, *, trained: bool = True, **extra):
        owner = get_user_model().objects.create_user(username, password="x-long-pass-1")
        model = services.model_create(owner=owner, name=f"{username}-car",
                                      track_id="racecraft_oval", action_space=action_space,
                                      reward_function="def reward_function(params):\n"
                                      "    return 1.0\n", validate_reward=False,
                                      **extra)  # fmt: skip
        if trained:
            torch.manual_seed(model.pk)
            weights = checkpoint_bytes(new_model(services.model_metadata(model)))
            get_store().put_bytes(keys_for(model.pk).best, weights)
            services.model_mark_checkpoint(model=model)
        return model

    return make
