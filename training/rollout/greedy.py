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
    return action_probabilities(policy, observations).argmax(dim=-1).cpu().numpy()


def action_probabilities(policy: ActorCriticPolicy, observations) -> torch.Tensor:
    """The action probabilities (softmax of the logits, one row per observation) of a discrete
    actor-critic policy for a batch of observations, in evaluation mode and without gradients."""
    if policy.training:
        policy.set_training_mode(False)
    with torch.inference_mode():
        tensor, _ = policy.obs_to_tensor(observations)
        features = policy.extract_features(tensor)
        if not policy.share_features_extractor:
            features = features[0]
        logits = policy.action_net(policy.mlp_extractor.forward_actor(features))
        return torch.softmax(logits, dim=-1)


def export_greedy(policy: BasePolicy) -> dict | None:
    """``policy``'s greedy choice as a :class:`~training.rollout.numpy_policy.GreedyNet`
    message, for a worker to drive an evaluation with; None where that network cannot say the
    same (SAC, continuous actions, camera + LIDAR, layers it does not know): the trainer then
    drives the evaluation itself with :func:`greedy_actions`. The weights are copies, taken
    now: the message drives with the policy as it is at this moment."""
    if not (isinstance(policy, ActorCriticPolicy) and isinstance(policy.action_space,
                                                                  spaces.Discrete)):  # fmt: skip
        return None
    space = policy.observation_space
    if not isinstance(space, spaces.Box) or len(space.shape) != 3:
        return None
    extractor = policy.pi_features_extractor  # the shared one, where they share it
    stacks = [getattr(extractor, "cnn", None), getattr(extractor, "linear", None),
              policy.mlp_extractor.policy_net, policy.action_net]  # fmt: skip
    layers: list[dict] = []
    for stack in stacks:
        modules = list(stack) if isinstance(stack, torch.nn.Sequential) else [stack]
        for module in modules:
            layer = _layer(module)
            if layer is None:
                return None
            layers.append(layer)
    return {
        "input_shape": [int(n) for n in space.shape],
        "divisor": 255.0 if policy.normalize_images else 1.0,
        "layers": layers,
    }


def _layer(module) -> dict | None:
    """One module as a GreedyNet layer; None for one it does not run."""
    nn = torch.nn

    def weights(m) -> dict:
        return {"weight": m.weight.detach().to("cpu", torch.float32).contiguous().numpy().copy(),
                "bias": m.bias.detach().to("cpu", torch.float32).numpy().copy()}  # fmt: skip

    if isinstance(module, nn.AvgPool2d):
        k, s = module.kernel_size, module.stride
        if (isinstance(k, int) and (s is None or s == k) and not module.padding
                and not module.ceil_mode):  # fmt: skip
            return {"op": "pool", "kernel": k}
        return None
    if isinstance(module, nn.Conv2d):
        k, s = module.kernel_size, module.stride
        plain = (module.padding in (0, (0, 0), "valid") and module.dilation == (1, 1)
                 and module.groups == 1 and module.bias is not None)  # fmt: skip
        if plain and k[0] == k[1] and s[0] == s[1]:
            return {"op": "conv", "stride": int(s[0]), **weights(module)}
        return None
    if isinstance(module, nn.Linear):
        return {"op": "dense", **weights(module)} if module.bias is not None else None
    if isinstance(module, nn.ReLU):
        return {"op": "relu"}
    if isinstance(module, nn.Tanh):
        return {"op": "tanh"}
    if isinstance(module, nn.Flatten):
        return {"op": "flatten"} if module.start_dim == 1 and module.end_dim == -1 else None
    return None
