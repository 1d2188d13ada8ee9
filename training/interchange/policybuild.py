"""The layers read from a DeepRacer graph or checkpoint, built into a Racecraft SB3 model.

:class:`NetworkLayers` is what :mod:`training.interchange.graphimport` and
:mod:`training.interchange.checkpointimport` read; :func:`build_policy` picks the network of
:data:`training.rl.policies.SPECS` whose shapes they have and copies the weights in, and
refuses a policy whose weights are not all finite once built (:func:`model_weights`).
:func:`refusing_bad_values` turns what a malformed upload makes numpy or torch raise (a
missing attribute, a shape that does not fit) into a :class:`GraphImportError` with its reason.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from torch import nn

from training.interchange.carmodel import CAMERA_HEIGHT, CAMERA_WIDTH, RACECRAFT_NETWORK_KEY
from training.interchange.integrity import first_non_finite
from training.rl.checkpoints import new_model
from training.rl.metadata import ModelMetadata
from training.rl.policies import DIRECT_HEADS, SPECS


class GraphImportError(ValueError):
    """A graph whose names, shapes or layers do not fit a Racecraft network; says which."""


@dataclass
class Layer:
    """One convolution or dense layer read from a graph or a checkpoint."""

    kind: str  # "conv" | "dense"
    kernel: np.ndarray  # conv HWIO, dense [in, out]
    stride: int = 1
    bias: np.ndarray | None = None
    activation: str | None = None


@dataclass
class NetworkLayers:
    """A network read from a graph: the camera path's layers to the head, and any LIDAR
    branch (:func:`build_policy` turns it into an SB3 model)."""

    scale: float = 1.0  # the graph's input is image * scale + offset
    offset: float = 0.0
    pool: int = 1
    layers: list[Layer] = field(default_factory=list)
    head: str = "linear"  # softmax | tanh | clip (already in the action's units) | linear
    concat: tuple[str, int] | None = None  # the ConcatV2 joining the LIDAR, layers before it
    lidar: list[Layer] = field(default_factory=list)  # the LIDAR embedder's dense layers


def _network(found: NetworkLayers, channels: int) -> str:
    """The Racecraft network whose layers have the graph's shapes."""
    convs = [
        (int(c.kernel.shape[3]), int(c.kernel.shape[0]), c.stride)
        for c in found.layers
        if c.kind == "conv"
    ]
    denses = [d for d in found.layers if d.kind == "dense"]
    if not convs or len(denses) not in (2, 3):
        raise GraphImportError(
            f"unsupported network: {len(convs)} convolutions and {len(denses)} dense layers"
        )
    direct = len(denses) == 2
    for name, (pool, spec, dense) in SPECS.items():
        if (name in DIRECT_HEADS) != direct:
            continue
        if pool == found.pool and spec == convs and denses[0].kernel.shape[1] == dense:
            if found.layers[0].kernel.shape[2] != channels:
                raise GraphImportError(
                    f"the first convolution takes {found.layers[0].kernel.shape[2]} channels, "
                    f"the sensor gives {channels}"
                )
            return name
    raise GraphImportError(
        f"unsupported network: convolutions (filters, kernel, stride) {convs}, pooling "
        f"{found.pool}, dense layers {[d.kernel.shape[1] for d in denses]} match no Racecraft "
        "network"
    )


def _copy(linear: nn.Module, kernel: np.ndarray, bias: np.ndarray | None, what: str) -> None:
    weight = torch.from_numpy(np.ascontiguousarray(kernel))
    if tuple(weight.shape) != tuple(linear.weight.shape):
        raise GraphImportError(
            f"{what}: the graph has shape {tuple(weight.shape)}, the network "
            f"{tuple(linear.weight.shape)}"
        )
    linear.weight.copy_(weight)
    linear.bias.copy_(
        torch.from_numpy(bias if bias is not None else np.zeros(weight.shape[0], np.float32))
    )


def _extractors(model: BaseAlgorithm) -> list[nn.Module]:
    if isinstance(model, SAC):
        return [
            model.actor.features_extractor,
            model.critic.features_extractor,
            model.critic_target.features_extractor,
        ]
    return [model.policy.features_extractor]


def _load(model: BaseAlgorithm, found: NetworkLayers, metadata: ModelMetadata) -> None:
    """Copy the graph's weights into ``model`` (torch sees images / 255 in C,H,W order)."""
    convs = [layer for layer in found.layers if layer.kind == "conv"]
    denses = [layer for layer in found.layers if layer.kind == "dense"]
    # graph input = pixels * scale + offset = (pixels / 255) * 255 * scale + offset
    first = convs[0].kernel
    conv_bias = [
        c.bias if c.bias is not None else np.zeros(c.kernel.shape[3], np.float32) for c in convs
    ]
    conv_bias[0] = conv_bias[0] + found.offset * first.sum(axis=(0, 1, 2))
    kernels = [c.kernel.transpose(3, 2, 0, 1) for c in convs]
    kernels[0] = kernels[0] * (255.0 * found.scale)
    for features in _extractors(model):
        extractor = features.camera if found.concat else features
        torch_convs = [m for m in extractor.cnn if isinstance(m, nn.Conv2d)]
        for i, (conv, kernel, bias) in enumerate(zip(torch_convs, kernels, conv_bias, strict=True)):
            _copy(conv, kernel, bias, f"convolution {i + 1}")
        h, w = _conv_output_size(found, convs)
        flat = denses[0].kernel.reshape(h, w, -1, denses[0].kernel.shape[1])
        _copy(
            extractor.linear[0],
            flat.transpose(3, 2, 0, 1).reshape(flat.shape[3], -1),
            denses[0].bias,
            "dense layer 1",
        )
        lidars = [m for m in features.lidar if isinstance(m, nn.Linear)] if found.concat else []
        for i, (layer, linear) in enumerate(zip(found.lidar, lidars, strict=True)):
            _copy(linear, layer.kernel.T, layer.bias, f"LIDAR dense layer {i + 1}")
    head = denses[-1]
    kernel, bias = (
        head.kernel.T,
        head.bias if head.bias is not None else np.zeros(head.kernel.shape[1], np.float32),
    )
    space = model.action_space
    if found.head == "linear" and metadata.action_space_type == "continuous":
        # DeepRacer's PPO mean is in -1..1 of the ranges; Racecraft's in the action's units
        half = (space.high - space.low) / 2.0
        kernel, bias = kernel * half[:, None], bias * half + space.low + half
    if isinstance(model, SAC):
        hidden, out = list(model.actor.latent_pi), model.actor.mu
    else:
        hidden, out = list(model.policy.mlp_extractor.policy_net), model.policy.action_net
    linears = [m for m in hidden if isinstance(m, nn.Linear)]
    for layer, linear in zip(denses[1:-1], linears, strict=True):
        _copy(linear, layer.kernel.T, layer.bias, "the policy's hidden layer")
    _copy(out, kernel.astype(np.float32), bias.astype(np.float32), "the policy head")


def _conv_output_size(found: NetworkLayers, convs: list[Layer]) -> tuple[int, int]:
    h, w = CAMERA_HEIGHT // found.pool, CAMERA_WIDTH // found.pool
    for conv in convs:
        k = conv.kernel.shape[0]
        h, w = (h - k) // conv.stride + 1, (w - k) // conv.stride + 1
    return h, w


def build_policy(
    found: NetworkLayers, metadata: ModelMetadata
) -> tuple[BaseAlgorithm, ModelMetadata]:
    """A new SB3 model of the Racecraft network ``found`` matches, holding its weights, and the
    metadata naming that network. Raises :class:`GraphImportError`."""
    network = _network(found, metadata.channels)
    extra = {k: v for k, v in metadata.extra.items() if k != RACECRAFT_NETWORK_KEY}
    metadata = dataclasses.replace(metadata, neural_network=network, extra=extra)
    model = new_model(metadata)
    with torch.no_grad(), np.errstate(over="ignore", invalid="ignore"):
        _load(model, found, metadata)  # an overflow is reported just below, with its weight
    bad = first_non_finite(model_weights(model))
    if bad is not None:  # finite weights that overflow float32 once the input scaling is folded
        raise GraphImportError(
            f"the policy's {bad[0]} holds {bad[1]} once built: the weights or the input "
            "scaling are too large for float32"
        )
    return model, metadata


def model_weights(model: BaseAlgorithm) -> Iterator[tuple[str, np.ndarray]]:
    """Every parameter of ``model``'s policy (its value function and critics included), by its
    torch name, as a numpy array."""
    for name, parameter in model.policy.named_parameters():
        yield name, parameter.detach().cpu().numpy()


@contextmanager
def refusing_bad_values(what: str, passing: tuple[type[Exception], ...] = ()) -> Iterator[None]:
    """Run an import step; what numpy, torch or a missing attribute raise on a malformed upload
    becomes a :class:`GraphImportError` saying so (``what`` names the upload's part). Errors
    of the ``passing`` types, which already say what is wrong, go through unchanged."""
    try:
        yield
    except (GraphImportError, *passing):
        raise
    except RecursionError:
        raise GraphImportError(f"the {what} is nested too deeply to read") from None
    except (
        ValueError,
        IndexError,
        KeyError,
        TypeError,
        ZeroDivisionError,
        OverflowError,
        RuntimeError,
    ) as exc:
        if "can't allocate memory" in str(exc):  # torch's allocator under the memory limit
            raise MemoryError(str(exc)) from None
        reason = str(exc)[:300]
        raise GraphImportError(
            f"the {what} does not fit a Racecraft network ({type(exc).__name__}: {reason})"
        ) from None
