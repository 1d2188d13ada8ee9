"""PPO's rollout buffer from whole episodes that simulation workers drove and streamed
(:mod:`training.rollout.streamed`): GAE(λ) per episode with the values the workers computed,
the episodes one after another as one env's steps."""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.buffers import RolloutBuffer

from training.rollout.streams import Chunk


def episode_advantages(rewards: np.ndarray, values: np.ndarray, *, terminated: bool,
                       bootstrap: float, gamma: float, lam: float) -> np.ndarray:  # fmt: skip
    """GAE(λ) advantages of one whole episode. A terminated episode's last step has no future;
    one cut by the time limit bootstraps from the value of its last observation (as SB3 does)."""
    n = len(rewards)
    advantages = np.zeros(n, np.float32)
    last = 0.0
    for t in reversed(range(n)):
        next_value = (0.0 if terminated else bootstrap) if t == n - 1 else values[t + 1]
        delta = rewards[t] + gamma * next_value - values[t]
        last = delta + (gamma * lam * last if t < n - 1 else 0.0)
        advantages[t] = last
    return advantages


def rollout_buffer(model, episodes: list[list[Chunk]]) -> RolloutBuffer:
    """PPO's rollout buffer (one env, the episodes one after another) from whole episodes."""
    parts = [_episode_arrays(model, chunks) for chunks in episodes]
    size = sum(len(p["rewards"]) for p in parts)
    buffer = RolloutBuffer(size, model.observation_space, model.action_space, device=model.device,
                           gamma=model.gamma, gae_lambda=model.gae_lambda, n_envs=1)  # fmt: skip
    for name in ("observations", "actions", "rewards", "values", "log_probs", "advantages",
                 "returns", "episode_starts"):  # fmt: skip
        data = np.concatenate([p[name] for p in parts])
        target = getattr(buffer, name)
        target[:] = data.reshape(target.shape)
    buffer.pos, buffer.full = size, True
    return buffer


def _episode_arrays(model, chunks: list[Chunk]) -> dict[str, np.ndarray]:
    obs = np.concatenate([c.obs for c in chunks])
    shape = model.observation_space.shape
    if obs.shape[1:] != shape:  # channel-last camera frames, as SB3's VecTransposeImage does
        obs = np.transpose(obs, (0, 3, 1, 2))
    rewards = np.concatenate([c.rewards for c in chunks])
    values = np.concatenate([c.values for c in chunks])
    last = chunks[-1]
    advantages = episode_advantages(rewards, values, terminated=last.terminated,
                                    bootstrap=last.bootstrap, gamma=model.gamma,
                                    lam=model.gae_lambda)  # fmt: skip
    starts = np.zeros(len(rewards), np.float32)
    starts[0] = 1.0
    return {
        "observations": obs, "actions": np.concatenate([c.actions for c in chunks]),
        "rewards": rewards, "values": values,
        "log_probs": np.concatenate([c.log_probs for c in chunks]),
        "advantages": advantages, "returns": advantages + values, "episode_starts": starts,
    }  # fmt: skip
