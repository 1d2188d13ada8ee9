"""The policy's own choice for one step (evaluations, the live view's laps): the action the
car would take, without SB3's ``predict`` around it.

A discrete actor-critic policy (PPO) picks the action with the highest probability, as
DeepRacer's car does with the exported graph's softmax output (an argmax over probabilities,
not logits: where two logits round to the same probability, both pick the first). Evaluations
step one car at a time, so the per-step overhead counts: SB3's ``predict`` builds a
distribution object and checks its arguments on every call (0.59 against 0.43 ms a frame for
the lean network on 2 CPU threads). Every other policy (SAC, a continuous action space) goes
through ``predict`` unchanged.
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy


def greedy_actions(policy: BasePolicy, observations) -> np.ndarray:
    """The deterministic actions of ``policy`` for a batch of observations (as a VecEnv gives
    them: channel-last images or a Dict of them), as ``policy.predict(..., deterministic=True)``
    returns them."""
    if not (isinstance(policy, ActorCriticPolicy) and isinstance(policy.action_space,
                                                                  spaces.Discrete)):  # fmt: skip
        actions, _ = policy.predict(observations, deterministic=True)
        return actions
    if policy.training:
        policy.set_training_mode(False)
    with torch.inference_mode():
        tensor, _ = policy.obs_to_tensor(observations)
        features = policy.extract_features(tensor)
        if not policy.share_features_extractor:
            features = features[0]
        logits = policy.action_net(policy.mlp_extractor.forward_actor(features))
        return torch.softmax(logits, dim=-1).argmax(dim=-1).cpu().numpy()
