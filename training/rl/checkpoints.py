"""Checkpoints: stable-baselines3 zips, loaded without trusting them.

A checkpoint is SB3's own ``model.save()`` zip, so it opens in SB3 anywhere. But ``PPO.load``
unpickles parts of that zip (policy class, spaces, schedules), and an imported model comes from
a user: unpickling it would run their code in our worker. So nothing here calls it. A model is
built from what we already know (algorithm, network, spaces from the model's metadata, or the
training env) and only tensors are copied in, read with ``torch.load(weights_only=True)``, which
refuses anything but tensors and plain containers.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm

from training.rl.metadata import ModelMetadata
from training.rl.policies import policy_kwargs, policy_type, sac_policy_kwargs

MAX_CHECKPOINT_BYTES = 1_000_000_000  # uncompressed tensors in one checkpoint zip


class CheckpointError(ValueError):
    """A checkpoint zip that does not load, or does not fit the model's metadata."""


# --- checkpoints ------------------------------------------------------------------------------


class _SpacesEnv(gym.Env):
    """An env that only carries the spaces, so SB3 can build a policy without a simulator."""

    def __init__(self, metadata: ModelMetadata) -> None:
        self.observation_space = metadata.observation_space
        self.action_space = metadata.actions.gym_space

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple:
        super().reset(seed=seed)
        return self._blank(), {}

    def step(self, action: Any) -> tuple:
        return self._blank(), 0.0, True, False, {}

    def _blank(self) -> Any:
        space = self.observation_space
        if isinstance(space, gym.spaces.Dict):
            return {k: np.zeros(s.shape, s.dtype) for k, s in space.spaces.items()}
        return np.zeros(space.shape, np.uint8)


def new_model(metadata: ModelMetadata) -> BaseAlgorithm:
    """An untrained SB3 model (CPU) of the metadata's algorithm, network and spaces.

    Its layers keep torch's default initialisation (SB3's orthogonal one is skipped: it takes
    seconds for DeepRacer's 5.8-million-weight dense layer, and callers load weights over it).
    """
    env = _SpacesEnv(metadata)
    network = metadata.neural_network
    space = env.observation_space
    if metadata.training_algorithm == "sac":
        kwargs = sac_policy_kwargs(network, space)
        return SAC(policy_type(space), env, policy_kwargs=kwargs, buffer_size=1, device="cpu")
    kwargs = {**policy_kwargs(network, space), "ortho_init": False}
    return PPO(policy_type(space), env, policy_kwargs=kwargs, n_steps=2, batch_size=2,
               device="cpu")  # fmt: skip


def read_checkpoint_tensors(zip_bytes: bytes) -> dict[str, Any]:
    """The ``*.pth`` members of an SB3 zip, loaded with ``weights_only=True`` (name → object).

    Raises :class:`CheckpointError` for a corrupt zip or more than 1 GB of tensors.
    """
    try:
        with zipfile.ZipFile(io.BytesIO(zip_bytes)) as archive:
            infos = archive.infolist()
            if len(infos) > 64 or sum(i.file_size for i in infos) > MAX_CHECKPOINT_BYTES:
                raise CheckpointError("the checkpoint is too large or has too many files")
            tensors = {}
            for info in infos:
                if info.filename.endswith(".pth") and "/" not in info.filename:
                    raw = archive.read(info)
                    tensors[info.filename[:-4]] = torch.load(
                        io.BytesIO(raw), map_location="cpu", weights_only=True
                    )
    except CheckpointError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError) as exc:
        raise CheckpointError(f"not a readable zip file ({exc})") from None
    except Exception as exc:  # torch.load raises many types for bad data
        raise CheckpointError(f"the tensors do not load ({type(exc).__name__}: {exc})") from None
    if "policy" not in tensors:
        raise CheckpointError("not a stable-baselines3 model (no policy.pth inside)")
    return tensors


def _check_shapes(state: Mapping[str, Any], metadata: ModelMetadata) -> None:
    """Clear messages for the common mismatches before the strict load."""
    sac = any(k.startswith("actor.") for k in state)
    algorithm = "sac" if sac else "clipped_ppo"
    if algorithm != metadata.training_algorithm:
        raise CheckpointError(
            f"the checkpoint is a {'SAC' if sac else 'PPO'} model but model_metadata.json "
            f"says training_algorithm {metadata.training_algorithm}"
        )
    convs = [v for v in state.values() if isinstance(v, torch.Tensor) and v.dim() == 4]
    if convs and convs[0].shape[1] != metadata.channels:
        raise CheckpointError(
            f"the checkpoint takes {convs[0].shape[1]}-channel images but the sensor "
            f"{metadata.camera} gives {metadata.channels}"
        )
    head = state.get("actor.mu.weight" if sac else "action_net.weight")
    if head is None:
        return
    outputs = int(head.shape[0])
    kind = metadata.action_space_type
    if kind == "discrete" and (outputs != len(metadata.actions.actions) or "log_std" in state):
        what = f"{outputs} discrete actions" if "log_std" not in state else "continuous actions"
        raise CheckpointError(
            f"the checkpoint has {what} but model_metadata.json lists "
            f"{len(metadata.actions.actions)} discrete actions"
        )
    if kind == "continuous" and (outputs != 2 or (not sac and "log_std" not in state)):
        raise CheckpointError(
            f"the checkpoint has {outputs} discrete actions but model_metadata.json has a "
            "continuous action space"
        )


def load_weights(
    model: BaseAlgorithm,
    zip_bytes: bytes,
    tensors: dict | None = None,
    *,
    fits: str = "this model's network, sensor or action space",
) -> None:
    """Copy a checkpoint's policy weights (and optimizer state when it fits) into ``model``.

    Raises :class:`CheckpointError` when the weights do not fit the model's network.
    """
    tensors = tensors if tensors is not None else read_checkpoint_tensors(zip_bytes)
    state = tensors["policy"]
    if not isinstance(state, Mapping):
        raise CheckpointError("policy.pth is not a state dict")
    try:
        model.policy.load_state_dict(state, strict=True)
    except (RuntimeError, KeyError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"the weights do not fit {fits} ({first})") from None
    for name in model._get_torch_save_params()[0]:  # e.g. policy.optimizer, actor.optimizer
        if name != "policy" and name in tensors:
            target = model
            for part in name.split("."):
                target = getattr(target, part)
            try:
                keep_step_kind(target, target.load_state_dict, tensors[name])
            except Exception:  # optimizer state is optional; training restarts its moments
                pass
    steps = checkpoint_data(zip_bytes).get("num_timesteps")
    if isinstance(steps, int) and steps >= 0:
        model.num_timesteps = steps


def keep_step_kind(optimizer: Any, load: Any, state: Any) -> None:
    """``load(state)`` into ``optimizer`` keeping how this machine runs its step.

    A checkpoint's optimizer state carries the saver's ``fused``/``foreach`` flags (torch copies
    whole parameter groups); the moments are what a checkpoint brings, the kind of step stays
    this model's (:func:`training.rl.algorithms.adam_kwargs`). A fused step wants its step
    counters as float tensors beside the weights.
    """
    flags = [{k: g.get(k) for k in ("fused", "foreach")} for g in optimizer.param_groups]
    load(state)
    for group, kept in zip(optimizer.param_groups, flags, strict=False):
        group.update(kept)
        if not kept.get("fused"):
            continue
        for param in group["params"]:
            step = optimizer.state.get(param, {}).get("step")
            if isinstance(step, torch.Tensor):
                optimizer.state[param]["step"] = step.to(param.device, torch.float32)


def checkpoint_data(zip_bytes: bytes) -> dict[str, Any]:
    """The plain-JSON entries of the checkpoint's ``data`` file (serialized ones left out)."""
    try:
        with zipfile.ZipFile(io.BytesIO(zip_bytes)) as archive:
            info = archive.getinfo("data")
            if info.file_size > 10_000_000:
                return {}
            raw = json.loads(archive.read(info))
    except (KeyError, ValueError, zipfile.BadZipFile):
        return {}
    if not isinstance(raw, dict):
        return {}
    return {k: v for k, v in raw.items() if not (isinstance(v, dict) and ":serialized:" in v)}


def load_checkpoint(zip_bytes: bytes, metadata: ModelMetadata) -> BaseAlgorithm:
    """A model of ``metadata``'s algorithm/network/spaces with the checkpoint's weights (and its
    optimizer state when that fits). Safe on untrusted bytes (nothing is unpickled).

    Raises :class:`CheckpointError` with a message fit for users.
    """
    tensors = read_checkpoint_tensors(zip_bytes)
    state = tensors["policy"]
    if not isinstance(state, Mapping):
        raise CheckpointError("policy.pth is not a state dict")
    _check_shapes(state, metadata)
    model = new_model(metadata)
    fits = f"neural_network {metadata.neural_network} with this sensor and action space"
    load_weights(model, zip_bytes, tensors, fits=fits)
    return model


def checkpoint_bytes(model: BaseAlgorithm) -> bytes:
    """``model.save()`` into memory: the zip that goes to the store."""
    buffer = io.BytesIO()
    model.save(buffer)
    return buffer.getvalue()
