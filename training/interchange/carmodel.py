"""The model a physical DeepRacer car loads: ``agent/model.pb`` + ``model_metadata.json``.

``model.pb`` is a frozen TensorFlow 1 graph written by :mod:`training.interchange.tfgraph` (no
TensorFlow needed) with DeepRacer's tensor names (deepracer-spec §6a), so the car's OpenVINO
model optimizer converts it with its own ``--input`` names and ``[1,120,160,C]`` shapes:

- input, float32 NHWC ``[-1, 120, 160, C]`` in 0..255 (the graph divides by 255 itself):
  ``main_level/agent/<main|policy>/online/network_0/<SENSOR>/<SENSOR>`` with ``<SENSOR>`` =
  ``FRONT_FACING_CAMERA`` (C = 1) or ``STEREO_CAMERAS`` (C = 2); ``main`` for PPO, ``policy``
  for SAC, as the car's model optimizer names them.
- with a LIDAR (``sensor`` lists one after the camera), a second input
  ``main_level/agent/<main|policy>/online/network_0/<LIDAR>/<LIDAR>``, float32 ``[-1, n]``
  (``LIDAR`` 64 ranges in metres, ``SECTOR_LIDAR`` 8, ``DISCRETIZED_SECTOR_LIDAR`` 64), through
  DeepRacer's LIDAR embedder, its features concatenated after the camera's (``ConcatV2``).
- output, the last node: PPO ``main_level/agent/main/online/network_1/ppo_head_0/policy``,
  SAC ``main_level/agent/policy/online/network_0/sac_policy_head_0/policy``. Discrete: softmax
  over the metadata's actions ``[-1, n]`` (the car takes the argmax). Continuous: ``[-1, 2]``
  = (steering, speed) in -1..1, which the car maps linearly onto the metadata's low..high: PPO's
  mean clipped to the ranges, SAC's tanh-squashed mean (Racecraft's deterministic action).

The torch layers map one to one: ``AvgPool2d`` → AvgPool, ``Conv2d`` → Conv2D + BiasAdd
(kernel OIHW → HWIO), ``Flatten`` → Reshape (the next dense kernel's rows are permuted from
torch's C,H,W order to TensorFlow's H,W,C), ``Linear`` → MatMul + BiasAdd, ReLU/Tanh.

``model_metadata.json`` names the network as DeepRacer's tools expect
(:data:`training.rl.policies.DEEPRACER_NAMES`): the car's web server never reads
``neural_network`` (it reads sensor, training_algorithm, action_space_type, action_space and
lidar_config), but DeepRacer-for-Cloud and the SimApp refuse unknown names. Racecraft's own
network is kept in :data:`RACECRAFT_NETWORK_KEY` so Racecraft can import the archive back.
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from torch import nn

from racing.lidar import (
    DISCRETIZED_CLIP_M,
    DISCRETIZED_VALUES,
    NUMBER_OF_SECTORS,
    SENSOR_DISCRETIZED_LIDAR,
)
from training.interchange.tarball import deterministic_tar_gz
from training.interchange.tfgraph import GraphWriter
from training.rl.checkpoints import load_checkpoint
from training.rl.metadata import ModelMetadata
from training.rl.policies import DEEPRACER_NAMES

RACECRAFT_NETWORK_KEY = "racecraft_neural_network"
PPO_SCOPE = "main_level/agent/main/online"
SAC_SCOPE = "main_level/agent/policy/online"
PPO_OUTPUT = f"{PPO_SCOPE}/network_1/ppo_head_0/policy"
SAC_OUTPUT = f"{SAC_SCOPE}/network_0/sac_policy_head_0/policy"
CAMERA_HEIGHT, CAMERA_WIDTH = 120, 160


class CarExportError(ValueError):
    """A model that cannot be written as a car model."""


def input_name(algorithm: str, sensor: str) -> str:
    """DeepRacer's input tensor name for ``algorithm`` (``clipped_ppo``/``sac``) and a sensor."""
    head = "policy" if algorithm == "sac" else "main"
    return f"main_level/agent/{head}/online/network_0/{sensor}/{sensor}"


def output_name(algorithm: str) -> str:
    """DeepRacer's output node name for ``algorithm``."""
    return SAC_OUTPUT if algorithm == "sac" else PPO_OUTPUT


def car_metadata(metadata: ModelMetadata) -> bytes:
    """``model_metadata.json`` for the car: DeepRacer's network name, Racecraft's kept aside;
    a discretized sector LIDAR's ``lidar_config`` (the car bins its scan with it) written as
    the simulator's, unless the metadata already has one."""
    data = metadata.to_json()
    if metadata.lidar == SENSOR_DISCRETIZED_LIDAR and "lidar_config" not in data:
        data["lidar_config"] = {
            "num_sectors": NUMBER_OF_SECTORS,
            "num_values_per_sector": DISCRETIZED_VALUES,
            "clipping_dist": DISCRETIZED_CLIP_M,
        }
    data["neural_network"] = DEEPRACER_NAMES[metadata.neural_network]
    if data["neural_network"] != metadata.neural_network:
        data[RACECRAFT_NETWORK_KEY] = metadata.neural_network
    return (json.dumps(data, indent=2, sort_keys=True) + "\n").encode()


def _policy_parts(model: BaseAlgorithm) -> tuple[nn.Module, list[nn.Module], nn.Linear]:
    """The policy's features extractor, the layers between it and the head, and the head."""
    if isinstance(model, SAC):
        actor = model.policy.actor
        return actor.features_extractor, list(actor.latent_pi), actor.mu
    policy = model.policy
    return policy.pi_features_extractor, list(policy.mlp_extractor.policy_net), policy.action_net


def conv_output_hwc(shape: tuple[int, int, int], conv: nn.Conv2d) -> tuple[int, int, int]:
    """The (H, W, C) a VALID convolution makes of an (H, W, C) input."""
    h, w, _ = shape
    kernel, stride = int(conv.kernel_size[0]), int(conv.stride[0])
    return (h - kernel) // stride + 1, (w - kernel) // stride + 1, int(conv.out_channels)


def tf_conv_kernel(conv: nn.Conv2d) -> np.ndarray:
    """A torch convolution's kernel (O, I, H, W) in TensorFlow's layout (H, W, I, O)."""
    return conv.weight.detach().cpu().numpy().transpose(2, 3, 1, 0)


def tf_flattened_kernel(kernel: np.ndarray, hwc: tuple[int, int, int]) -> np.ndarray:
    """A dense kernel ``[out, C*H*W]`` over torch's flattened features, its rows reordered for
    TensorFlow's H, W, C flatten of an (H, W, C) tensor: ``[out, H*W*C]``."""
    h, w, c = hwc
    return kernel.reshape(-1, c, h, w).transpose(0, 2, 3, 1).reshape(kernel.shape[0], -1)


class _Emitter:
    """Writes torch layers as graph nodes, tracking the NHWC shape of the running tensor."""

    def __init__(self, writer: GraphWriter, scope: str, shape: tuple[int, int, int]) -> None:
        self.writer, self.scope = writer, scope
        self.shape: tuple[int, ...] = shape  # (H, W, C) before Flatten, (features,) after
        self.flatten_hwc: tuple[int, int, int] | None = None
        self.count = 0

    def _name(self, kind: str) -> str:
        self.count += 1
        return f"{self.scope}/{kind}_{self.count}"

    def layer(self, x: str, layer: nn.Module) -> str:
        w = self.writer
        if isinstance(layer, nn.AvgPool2d):
            size = int(
                layer.kernel_size if isinstance(layer.kernel_size, int) else layer.kernel_size[0]
            )
            h, wd, c = self.shape
            self.shape = (h // size, wd // size, c)
            return w.avg_pool(self._name("AvgPool"), x, size)
        if isinstance(layer, nn.Conv2d):
            self.shape = conv_output_hwc(self.shape, layer)  # type: ignore[arg-type]
            bias = layer.bias.detach().numpy()
            return w.conv2d(
                self._name("Conv2d"), x, tf_conv_kernel(layer), bias, int(layer.stride[0])
            )
        if isinstance(layer, nn.Flatten):
            self.flatten_hwc = self.shape  # type: ignore[assignment]
            self.shape = (int(np.prod(self.shape)),)
            return w.flatten(self._name("Flatten"), x, self.shape[0])
        if isinstance(layer, nn.Linear):
            kernel = layer.weight.detach().numpy()  # [out, in]
            if self.flatten_hwc is not None:  # torch flattened C,H,W; TensorFlow H,W,C
                kernel = tf_flattened_kernel(kernel, self.flatten_hwc)
                self.flatten_hwc = None
            self.shape = (kernel.shape[0],)
            return w.dense(self._name("Dense"), x, kernel.T, layer.bias.detach().numpy())
        if isinstance(layer, nn.ReLU | nn.Tanh):
            return w.unary("Relu" if isinstance(layer, nn.ReLU) else "Tanh", self._name("Act"), x)
        raise CarExportError(f"no car graph for the layer {type(layer).__name__}")


def export_car_graph(model: BaseAlgorithm, metadata: ModelMetadata) -> bytes:
    """The frozen TensorFlow graph (``model.pb`` bytes) of ``model``'s policy, for the car.

    ``model`` is an SB3 PPO/SAC model of a Racecraft network (:mod:`training.rl.policies`)
    taking ``(C, 120, 160)`` images (and, with a LIDAR, the LIDAR vector). Raises
    :class:`CarExportError` for another policy.
    """
    algorithm = "sac" if isinstance(model, SAC) else "clipped_ppo"
    if algorithm != metadata.training_algorithm:
        raise CarExportError(f"the model is {algorithm} but the metadata says otherwise")
    space = model.policy.observation_space
    lidar = metadata.lidar
    if isinstance(space, gym.spaces.Dict) != (lidar is not None):
        raise CarExportError("the policy's inputs do not match the metadata's sensor list")
    camera_space = space.spaces[metadata.camera] if lidar else space
    shape = tuple(camera_space.shape)
    if shape != (metadata.channels, CAMERA_HEIGHT, CAMERA_WIDTH):
        raise CarExportError(f"the policy takes images of shape {shape}, not (C, 120, 160)")
    scope = f"{SAC_SCOPE}/network_0" if algorithm == "sac" else f"{PPO_SCOPE}/network_1"
    writer = GraphWriter()
    extractor, latent, head = _policy_parts(model)
    camera = extractor.camera if lidar else extractor
    with torch.no_grad():
        x, emitter = _camera_branch(writer, scope, algorithm, metadata.camera, shape[0], camera)
        if lidar:
            size = int(space.spaces[lidar].shape[0])
            y = writer.placeholder(input_name(algorithm, lidar), [-1, size])
            emitter = _Emitter(writer, f"{scope}/{lidar}", (size,))
            for layer in extractor.lidar:
                y = emitter.layer(y, layer)
            x = writer.concat(f"{scope}/middleware_concat", [x, y])
            emitter = _Emitter(writer, f"{scope}/middleware", (int(extractor.features_dim),))
        for layer in latent:
            x = emitter.layer(x, layer)
        _head(writer, emitter, x, head, model, algorithm)
    return writer.serialize()


def _camera_branch(
    writer: GraphWriter, scope: str, algorithm: str, sensor: str, channels: int, camera: nn.Module
) -> tuple[str, _Emitter]:
    """The camera input (0..255), its /255 and the camera network up to its features; the
    emitter goes on with the layers after them (camera-only graphs keep their node names)."""
    x = writer.placeholder(
        input_name(algorithm, sensor), [-1, CAMERA_HEIGHT, CAMERA_WIDTH, channels]
    )
    sensor_scope = f"{scope}/{sensor}"
    x = writer.binary(
        "RealDiv", f"{sensor_scope}/truediv", x, writer.const(f"{sensor_scope}/truediv/y", 255.0)
    )
    emitter = _Emitter(writer, sensor_scope, (CAMERA_HEIGHT, CAMERA_WIDTH, channels))
    for layer in [*camera.cnn, *camera.linear]:
        x = emitter.layer(x, layer)
    return x, emitter


def _head(
    writer: GraphWriter, emitter: _Emitter, x: str, head: nn.Linear, model: BaseAlgorithm,
    algorithm: str,
) -> None:  # fmt: skip
    """The last nodes, ending at :func:`output_name`."""
    head_scope = output_name(algorithm).rsplit("/", 1)[0]
    emitter.scope = head_scope
    logits = emitter.layer(x, head)
    space = model.action_space
    out = output_name(algorithm)
    if isinstance(space, gym.spaces.Discrete):
        writer.unary("Softmax", out, logits)
        return
    if algorithm == "sac":
        writer.unary("Tanh", out, logits)
        return
    # PPO's mean is in the action's units: clip to low..high, then map onto -1..1.
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    clipped = writer.binary(
        "Maximum", f"{head_scope}/clip_low", logits, writer.const(f"{head_scope}/low", low)
    )
    clipped = writer.binary(
        "Minimum", f"{head_scope}/clip_high", clipped, writer.const(f"{head_scope}/high", high)
    )
    scaled = writer.binary(
        "Mul",
        f"{head_scope}/scale",
        clipped,
        writer.const(f"{head_scope}/scale/y", 2.0 / (high - low)),
    )
    writer.binary(
        "Add", out, scaled, writer.const(f"{head_scope}/offset", -1.0 - 2.0 * low / (high - low))
    )


def build_car_archive(metadata: ModelMetadata, model: BaseAlgorithm | bytes) -> bytes:
    """ "Download for the car": a tar.gz of ``agent/model.pb`` and ``model_metadata.json``.

    ``model`` is an SB3 model or its checkpoint zip (loaded safely with
    :func:`training.rl.checkpoints.load_checkpoint`). The archive is byte-for-byte
    reproducible. Raises :class:`CarExportError` or ``CheckpointError``.
    """
    if isinstance(model, bytes | bytearray | memoryview):
        model = load_checkpoint(bytes(model), metadata)
    files = {
        "agent/model.pb": export_car_graph(model, metadata),
        "model_metadata.json": car_metadata(metadata),
    }
    return deterministic_tar_gz(files)
