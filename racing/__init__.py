"""Racecraft's simulator: DeepRacer tracks, a PyBullet car, fast cameras, DeepRacer's reward
params and race rules, and the Gymnasium environment. A pure library: no Django here."""

from racing.registration import ENV_ID, register_envs

register_envs()

__all__ = ["ENV_ID", "register_envs"]
