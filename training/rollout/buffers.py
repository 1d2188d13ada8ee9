"""PPO's rollout buffer, filled one way for both sources of experience: the steps of a rollout
as arrays, then SB3's own GAE(λ) (``RolloutBuffer.compute_returns_and_advantage``), as its
``collect_rollouts`` leaves the buffer.

- Lockstep (:func:`~training.rollout.lockstep.fill_sampled_rollout`): the workers drove
  ``n_envs`` cars for the buffer's steps; the trainer computes the values and
  log-probabilities afterwards.
- Streamed (:func:`rollout_buffer`): whole episodes that simulation workers drove and streamed
  (:mod:`training.rollout.streamed`), with the values and log-probabilities they computed, one
  after another as one env's steps.

Either way an episode cut by the time limit has γ × the value of its last observation added to
its last reward, as SB3 does, and an episode that ends inside the rollout ends its GAE there.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.buffers import RolloutBuffer

from training.rollout.streams import Chunk


def fill_rollout_buffer(buffer: RolloutBuffer, *, observations: np.ndarray,
                        actions: np.ndarray, rewards: np.ndarray, episode_starts: np.ndarray,
                        values: np.ndarray, log_probs: np.ndarray, last_values: torch.Tensor,
                        dones: np.ndarray) -> None:  # fmt: skip
    """Fill ``buffer`` with a whole rollout: every array holds ``buffer_size`` × ``n_envs``
    steps (in that order; observations channel-first as the policy takes them). ``rewards``
    already hold a cut episode's bootstrap; ``last_values`` (``n_envs``) are the values of the
    observations after the rollout and ``dones`` (``n_envs``) whether its last step ended an
    episode, for the returns of the last steps. Then the advantages and returns, by SB3.

    :raises RuntimeError: the arrays do not hold as many steps as the buffer."""
    if np.size(rewards) != buffer.buffer_size * buffer.n_envs:
        raise RuntimeError(f"a rollout of {np.size(rewards)} steps for a buffer of "
                           f"{buffer.buffer_size}×{buffer.n_envs}")  # fmt: skip
    buffer.reset()
    for name, data in (("observations", observations), ("actions", actions),
                       ("rewards", rewards), ("episode_starts", episode_starts),
                       ("values", values), ("log_probs", log_probs)):  # fmt: skip
        target = getattr(buffer, name)
        target[:] = np.asarray(data).reshape(target.shape)
    buffer.pos, buffer.full = buffer.buffer_size, True
    buffer.compute_returns_and_advantage(last_values=last_values, dones=np.asarray(dones))


def rollout_buffer(model, episodes: list[list[Chunk]]) -> RolloutBuffer:
    """PPO's rollout buffer (one env, the episodes one after another) from whole episodes,
    each its chunks in order."""
    parts = [_episode_arrays(model, chunks) for chunks in episodes]
    size = sum(len(p["rewards"]) for p in parts)
    buffer = RolloutBuffer(size, model.observation_space, model.action_space, device=model.device,
                           gamma=model.gamma, gae_lambda=model.gae_lambda, n_envs=1)  # fmt: skip
    arrays = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    # Every episode ends inside the rollout: nothing after it to bootstrap from.
    fill_rollout_buffer(buffer, **arrays, last_values=torch.zeros(1), dones=np.ones(1))
    return buffer


def _episode_arrays(model, chunks: list[Chunk]) -> dict[str, np.ndarray]:
    obs = np.concatenate([c.obs for c in chunks])
    shape = model.observation_space.shape
    if obs.shape[1:] != shape:  # channel-last camera frames, as SB3's VecTransposeImage does
        obs = np.transpose(obs, (0, 3, 1, 2))
    rewards = np.concatenate([c.rewards for c in chunks]).astype(np.float32)
    last = chunks[-1]
    if not last.terminated:  # cut by the time limit: its future is the last value's
        rewards[-1] += model.gamma * last.bootstrap
    starts = np.zeros(len(rewards), np.float32)
    starts[0] = 1.0
    return {
        "observations": obs, "actions": np.concatenate([c.actions for c in chunks]),
        "rewards": rewards, "episode_starts": starts,
        "values": np.concatenate([c.values for c in chunks]),
        "log_probs": np.concatenate([c.log_probs for c in chunks]),
    }  # fmt: skip
