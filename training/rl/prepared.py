"""A policy update that prepares the rollout's camera images once, not once per minibatch.

PPO goes over a rollout ``num_epochs`` times (DeepRacer's default: 10). Before this, every
minibatch turned its 160×120 camera images into floats (÷255) and averaged them to 80×60
(the lean network's first layer, which has no weights) again in every epoch: on a 2-core CPU
that was a fifth of an update (``bench/bench_update.py``). :func:`prepare_rollout` does it once
for the whole rollout and puts the result in the buffer in place of the raw images, and
:func:`evaluate_prepared` runs the policy from there. The arithmetic is the same operation on
the same numbers, so an update gives bit for bit the results it gave before
(tests/training/rl/test_prepared.py holds it to that).

Only networks that average pixels first take this path (DeepRacer's own CNNs start with a
convolution: their prepared images would only be the raw ones as floats, four times the
memory for nothing), and only where the policy shares one feature extractor between its
actor and its critic, as every Racecraft policy does.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.buffers import DictRolloutBuffer, RolloutBuffer
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import preprocess_obs

CHUNK = 32
"""Images prepared at a time: their float copy (2.5 MB for 32 camera frames) stays in the
CPU's cache between the steps of the preparation. 2,000 frames took 43 ms in chunks of 32
against 212 ms in chunks of 512 (2-core AMD EPYC), the same numbers."""


def _camera_key(policy: ActorCriticPolicy) -> str | None:
    return getattr(policy.features_extractor, "camera_key", None)


def preparable(policy: ActorCriticPolicy) -> bool:
    """Whether ``policy``'s updates can start from prepared images."""
    extractor = policy.features_extractor
    return (
        policy.share_features_extractor
        and getattr(extractor, "pooling", 1) > 1
        and hasattr(extractor, "forward_prepared")
    )


def prepare_rollout(policy: ActorCriticPolicy, buffer: RolloutBuffer) -> None:
    """Replace the buffer's camera images by the network's prepared input (float32, pooled).

    Call it once a rollout is complete and before the buffer hands out minibatches
    (``buffer.get``); the buffer's next ``reset`` allocates raw image storage again.
    """
    key = _camera_key(policy)
    space = policy.observation_space[key] if key else policy.observation_space
    images = buffer.observations[key] if key else buffer.observations
    lead = images.shape[:2]  # (steps, envs)
    flat = images.reshape(-1, *images.shape[2:])
    extractor = policy.features_extractor
    parts = []
    with torch.no_grad():
        for start in range(0, len(flat), CHUNK):
            batch = torch.as_tensor(flat[start : start + CHUNK], device=policy.device)
            batch = preprocess_obs(batch, space, normalize_images=policy.normalize_images)
            parts.append(extractor.prepare(batch).cpu().numpy())
    prepared = np.concatenate(parts).reshape(*lead, *parts[0].shape[1:])
    if isinstance(buffer, DictRolloutBuffer):
        buffer.observations[key] = prepared
    else:
        buffer.observations = prepared


def evaluate_prepared(
    policy: ActorCriticPolicy, observations, actions: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """SB3's ``ActorCriticPolicy.evaluate_actions`` from a minibatch of prepared observations
    (a shared feature extractor): values, log-probabilities of ``actions``, entropy."""
    key = _camera_key(policy)
    if key is not None:
        observations = {
            name: value
            if name == key
            else preprocess_obs(
                value, policy.observation_space[name], normalize_images=policy.normalize_images
            )
            for name, value in observations.items()
        }
    features = policy.features_extractor.forward_prepared(observations)
    latent_pi, latent_vf = policy.mlp_extractor(features)
    distribution = policy._get_action_dist_from_latent(latent_pi)
    log_prob = distribution.log_prob(actions)
    values = policy.value_net(latent_vf)
    return values, log_prob, distribution.entropy()
