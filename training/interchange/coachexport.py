"""A Racecraft PPO model as the TensorFlow checkpoint DeepRacer's own trainer (Coach, in the
SimApp) writes, so DeepRacer-on-AWS (DRoA) imports the virtual model and races or trains it on.

DRoA's import runs DeepRacer's model validation (the SimApp's ``markov/validation_worker.py``):
it builds Coach's graph from ``model_metadata.json`` and restores the checkpoints that
``deepracer_checkpoints.json`` names (best and last) with Coach's ``GlobalVariableSaver``,
which assigns every variable of the online networks by name and shape. So the checkpoint holds
exactly those variables, with these names (read off the SimApp's Coach graph for a clipped-PPO
model; ``<S>`` is ``FRONT_FACING_CAMERA`` or ``STEREO_CAMERAS``, all under
``main_level/agent/main/online/``):

- ``network_1`` (the policy) and ``network_0`` (the value): each its own convolutions
  ``<S>/Conv2d_<0,2,4..>/kernel|bias`` (HWIO), for the 5-layer network also
  ``<S>/Dense_8/kernel|bias`` (a 64→64 dense on every pixel of the last convolution, then a
  ReLU), ``middleware_fc_embedder/Dense_0/kernel|bias`` over the flattened H,W,C features, and
  ``gradients_from_head_0-0_rescalers`` (a scalar, 1);
- the heads: ``network_1/ppo_head_0/policy_fc/kernel|bias`` (discrete: the logits of the
  metadata's actions) or ``network_1/ppo_head_0/policy_mean/kernel|bias`` and
  ``policy_log_std`` ``[1, 2]`` (continuous, in -1..1 of the ranges), and
  ``network_0/v_values_head_0/output/kernel|bias``.

Adam's slots, its beta powers and the global step are not restored (they start afresh when
DeepRacer trains on); target networks are copied from the online ones.

Racecraft's PPO shares one camera network between policy and value; it is written into both of
Coach's networks, so the policy and the value function are the same functions in DeepRacer. Only
the networks laid out as DeepRacer lays them out can be written (:data:`COACH_NETWORKS`: the
"heads as in AWS" networks, whose heads sit on the 512-unit dense layer); with the 5-layer one,
``Dense_8`` is the identity (exact: it follows a ReLU and is followed by one). SAC (DeepRacer's
policy head has a hidden 256-unit layer) and LIDAR models (DeepRacer feeds the LIDAR into the
dense layer with the flattened camera features) cannot; :func:`coach_export_refusal` says why.
The virtual-model download carries the checkpoint for the 3-layer network only
(:func:`download_refusal`).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from torch import nn

from training.interchange.carmodel import (
    CAMERA_HEIGHT,
    CAMERA_WIDTH,
    PPO_SCOPE,
    conv_output_hwc,
    tf_conv_kernel,
    tf_flattened_kernel,
)
from training.interchange.tfcheckpoint import write_checkpoint
from training.rl.checkpoints import checkpoint_data
from training.rl.metadata import ModelMetadata
from training.rl.policies import AWS_SHALLOW, AWS_STANDARD, NETWORK_LABELS

COACH_NETWORKS = {AWS_SHALLOW: 0, AWS_STANDARD: 64}
"""The networks DeepRacer's Coach graph can hold, with the width of the per-pixel dense layer
its scheme puts after the convolutions (0: none)."""
RESCALER = "gradients_from_head_0-0_rescalers"


class CoachExportError(ValueError):
    """A model DeepRacer's trainer cannot hold."""


def coach_export_refusal(metadata: ModelMetadata) -> str | None:
    """Why DeepRacer-on-AWS could not import this model's weights, or None when it can."""
    if metadata.training_algorithm != "clipped_ppo":
        return (
            "DeepRacer's SAC policy has a hidden 256-unit layer that Racecraft's SAC does not; "
            "only PPO models can be written as DeepRacer checkpoints"
        )
    if metadata.lidar is not None:
        return (
            f"DeepRacer feeds the {metadata.lidar} into the dense layer beside the camera's "
            "features, which Racecraft's LIDAR network does not; only camera models can be "
            "written as DeepRacer checkpoints"
        )
    if metadata.neural_network not in COACH_NETWORKS:
        choices = " or ".join(f'"{NETWORK_LABELS[n]}"' for n in COACH_NETWORKS)
        label = NETWORK_LABELS.get(metadata.neural_network, metadata.neural_network)
        return (
            f'its network ("{label}") is not laid out as DeepRacer\'s; a model trained with '
            f"{choices} can be written as a DeepRacer checkpoint"
        )
    return None


DOWNLOAD_NETWORKS = (AWS_SHALLOW,)
"""The networks whose DeepRacer checkpoint goes into the virtual-model download. The 5-layer
network's holds 230 MB (DeepRacer keeps a copy of the network for the value function), which
would take the download past the 200 MB that Racecraft imports back."""


def download_refusal(metadata: ModelMetadata) -> str | None:
    """Why the virtual-model download holds no DeepRacer checkpoint for this model (so
    DeepRacer-on-AWS's validation would refuse it), or None when it holds one."""
    refusal = coach_export_refusal(metadata)
    if refusal is None and metadata.neural_network not in DOWNLOAD_NETWORKS:
        refusal = (
            "the 5-layer network's DeepRacer checkpoint holds 230 MB (a copy of the network "
            "for the value function), which would take the download past the 200 MB that "
            f'Racecraft imports back; train with "{NETWORK_LABELS[AWS_SHALLOW]}" to take a '
            "model to DeepRacer-on-AWS"
        )
    return refusal


def _numpy(parameter: torch.Tensor) -> np.ndarray:
    return parameter.detach().cpu().numpy().astype(np.float32)


def _camera_variables(
    extractor: nn.Module, scope: str, camera: str, channels: int, per_pixel: int
) -> dict[str, np.ndarray]:
    """A camera network's convolutions, its optional per-pixel dense layer and the middleware
    dense layer, by Coach's names under ``scope``."""
    found: dict[str, np.ndarray] = {}
    hwc = (CAMERA_HEIGHT, CAMERA_WIDTH, channels)
    convs = [layer for layer in extractor.cnn if isinstance(layer, nn.Conv2d)]
    for i, conv in enumerate(convs):
        hwc = conv_output_hwc(hwc, conv)
        found[f"{scope}/{camera}/Conv2d_{2 * i}/kernel"] = tf_conv_kernel(conv).astype(np.float32)
        found[f"{scope}/{camera}/Conv2d_{2 * i}/bias"] = _numpy(conv.bias)
    if per_pixel:
        c = hwc[2]
        if per_pixel != c:
            raise CoachExportError(f"the last convolution has {c} filters, not {per_pixel}")
        dense = f"{scope}/{camera}/Dense_{2 * len(convs)}"
        found[f"{dense}/kernel"] = np.eye(c, dtype=np.float32)
        found[f"{dense}/bias"] = np.zeros(c, np.float32)
    linear = extractor.linear[0]
    kernel = tf_flattened_kernel(_numpy(linear.weight), hwc)
    found[f"{scope}/middleware_fc_embedder/Dense_0/kernel"] = np.ascontiguousarray(kernel.T)
    found[f"{scope}/middleware_fc_embedder/Dense_0/bias"] = _numpy(linear.bias)
    found[f"{scope}/{RESCALER}"] = np.float32(1.0)
    return found


def coach_variables(model: BaseAlgorithm, metadata: ModelMetadata) -> dict[str, np.ndarray]:
    """The variables DeepRacer's validation restores, from a Racecraft PPO model of
    ``metadata`` (see the module docstring). Raises :class:`CoachExportError`."""
    refusal = coach_export_refusal(metadata)
    if refusal:
        raise CoachExportError(refusal)
    if not isinstance(model, PPO):
        raise CoachExportError("the model is not a PPO model")
    policy = model.policy
    if len(policy.mlp_extractor.policy_net) or len(policy.mlp_extractor.value_net):
        raise CoachExportError("the policy has hidden layers before its heads")
    per_pixel = COACH_NETWORKS[metadata.neural_network]
    camera, channels = metadata.camera, metadata.channels
    found = _camera_variables(
        policy.pi_features_extractor, f"{PPO_SCOPE}/network_1", camera, channels, per_pixel
    )
    found |= _camera_variables(
        policy.vf_features_extractor, f"{PPO_SCOPE}/network_0", camera, channels, per_pixel
    )
    head = f"{PPO_SCOPE}/network_1/ppo_head_0"
    weight, bias = _numpy(policy.action_net.weight), _numpy(policy.action_net.bias)
    space = model.action_space
    if isinstance(space, gym.spaces.Discrete):
        found[f"{head}/policy_fc/kernel"] = np.ascontiguousarray(weight.T)
        found[f"{head}/policy_fc/bias"] = bias
    else:
        # Racecraft's mean is in the action's units; DeepRacer's in -1..1 of low..high.
        low, high = space.low.astype(np.float64), space.high.astype(np.float64)
        scale, middle = 2.0 / (high - low), (high + low) / 2.0
        found[f"{head}/policy_mean/kernel"] = (weight.T * scale).astype(np.float32)
        found[f"{head}/policy_mean/bias"] = ((bias - middle) * scale).astype(np.float32)
        log_std = _numpy(policy.log_std) + np.log(scale)
        found[f"{head}/policy_log_std"] = log_std.astype(np.float32).reshape(1, -1)
    value = f"{PPO_SCOPE}/network_0/v_values_head_0/output"
    found[f"{value}/kernel"] = np.ascontiguousarray(_numpy(policy.value_net.weight).T)
    found[f"{value}/bias"] = _numpy(policy.value_net.bias)
    return found


def checkpoint_name(zip_bytes: bytes) -> str:
    """DeepRacer's name for a checkpoint, ``<iteration>_Step-<steps>.ckpt`` (the SimApp
    validates names it can split at ``_Step`` into an iteration number), from the SB3 zip's
    plain entries: its policy updates over its epochs, and its environment steps."""
    data = checkpoint_data(zip_bytes)
    updates, epochs, steps = (data.get(k) for k in ("_n_updates", "n_epochs", "num_timesteps"))
    ok = all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (updates, steps))
    iteration = updates // epochs if ok and isinstance(epochs, int) and epochs > 0 else 0
    return f"{iteration}_Step-{steps if ok else 0}.ckpt"


def droa_checkpoint_files(
    zip_bytes: bytes, metadata: ModelMetadata, model: BaseAlgorithm
) -> tuple[str, dict[str, bytes]]:
    """The checkpoint's name and the files DeepRacer-on-AWS's validation restores it from,
    by their names in the model folder: ``model/<name>.index``,
    ``model/<name>.data-00000-of-00001`` and ``model/.coach_checkpoint`` (the name, no newline,
    as the SimApp writes it; the validation needs it). ``model`` is the zip's model, loaded.
    Raises :class:`CoachExportError`."""
    name = checkpoint_name(zip_bytes)
    index, data = write_checkpoint(coach_variables(model, metadata))
    return name, {
        f"model/{name}.index": index,
        f"model/{name}.data-00000-of-00001": data,
        "model/.coach_checkpoint": name.encode(),
    }
