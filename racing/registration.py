"""Versioned Gymnasium ids, registered in one place."""

from __future__ import annotations

import gymnasium as gym

ENV_ID = "racecraft/Racing-v0"
"""``gymnasium.make(ENV_ID, track=..., ...)`` builds a :class:`racing.env.RacingEnv`."""


def register_envs() -> None:
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="racing.env:RacingEnv")
