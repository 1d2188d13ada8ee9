"""The speed-ups of the trainer's forward and backward passes give the numbers of the plain
layers, bit for bit: the 2×2 averaging (policies.average_pool), the copy before the last ReLU
(CameraExtractor.forward_prepared), torch's distributions without argument checks. An
export still sees the plain layers."""

from __future__ import annotations

import io

import gymnasium as gym
import numpy as np
import onnx
import pytest
import torch
import torch.nn.functional as F
from stable_baselines3.common.vec_env import DummyVecEnv
from torch import nn

from training.rl.algorithms import build_model
from training.rl.policies import LEAN, TINY, CameraExtractor, average_pool
from training.rl.presets import RACING


def camera_frames(batch: int, channels: int = 1, rows: int = 120, cols: int = 160) -> torch.Tensor:
    generator = torch.Generator().manual_seed(batch + channels)
    pixels = torch.randint(0, 256, (batch, channels, rows, cols), generator=generator)
    return pixels.to(torch.uint8).float() / 255  # as SB3 hands camera frames over


@pytest.mark.parametrize("size", [2, 3, 8])
@pytest.mark.parametrize("channels", [1, 2])
@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
def test_average_pool_is_the_layer_bit_for_bit(size, channels, layout):
    images = camera_frames(6, channels).contiguous(memory_format=layout)
    assert torch.equal(average_pool(images, size), F.avg_pool2d(images, size))


def test_average_pool_drops_what_the_layer_drops():
    images = camera_frames(3, 1, 121, 163)
    pooled = average_pool(images, 2)
    assert pooled.shape == (3, 1, 60, 81)
    assert torch.equal(pooled, F.avg_pool2d(images, 2))


class Frames(gym.Env):
    observation_space = gym.spaces.Box(0, 255, (120, 160, 1), np.uint8)
    action_space = gym.spaces.Discrete(len(RACING.action_space))

    def reset(self, *, seed=None, options=None):
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), 0.0, False, False, {}


def lean_model():
    return build_model("clipped_ppo", DummyVecEnv([Frames]), RACING.hyperparameters, seed=3)


def plain_features(extractor: CameraExtractor, images: torch.Tensor) -> torch.Tensor:
    """The extractor's layers one after the other, as torch runs them."""
    x = images
    for layer in extractor.cnn:
        x = layer(x)
    return extractor.linear(x)


def test_the_lean_network_gives_the_plain_layers_numbers_and_gradients():
    """build_model puts the convolutions in channels-last (the CPU's faster layout); the
    features and every weight's gradient are those of the plain layers."""
    extractor = lean_model().policy.features_extractor
    assert extractor.cnn[1].weight.is_contiguous(memory_format=torch.channels_last)
    images = camera_frames(64)
    weights = torch.randn(64, 256, generator=torch.Generator().manual_seed(1))

    def run(forward):
        extractor.zero_grad()
        features = forward(images)
        (features * weights).sum().backward()
        return features.detach(), [p.grad.clone() for p in extractor.parameters()]

    fast, fast_grads = run(extractor)
    plain, plain_grads = run(lambda x: plain_features(extractor, x))
    assert torch.equal(fast, plain)
    assert all(torch.equal(a, b) for a, b in zip(fast_grads, plain_grads, strict=True))
    prepared = extractor.prepare(images)
    assert torch.equal(prepared, F.avg_pool2d(images, 2))
    assert torch.equal(extractor.forward_prepared(prepared).detach(), plain)


def test_the_tiny_networks_8x8_averaging_keeps_the_layer():
    extractor = CameraExtractor(gym.spaces.Box(0, 1, (1, 120, 160), np.float32), TINY)
    images = camera_frames(4)
    assert torch.equal(extractor.prepare(images), extractor.cnn[0](images))


def test_an_onnx_export_keeps_the_averaging_layer():
    from training.interchange.export import export_onnx

    graph = onnx.load_from_string(export_onnx(lean_model())).graph
    ops = {node.op_type for node in graph.node}
    assert "AveragePool" in ops
    assert "Slice" not in ops


def test_distributions_skip_their_argument_checks_and_still_refuse_nan():
    lean_model()  # importing the algorithms switched the checks off
    assert torch.distributions.Distribution._validate_args is False
    with pytest.raises(RuntimeError, match="nan"):
        torch.distributions.Categorical(logits=torch.tensor([[float("nan"), 0.0]])).sample()


def test_a_network_without_a_flattening_copy_is_left_alone():
    """With weights in torch's default layout, nothing is copied before the last ReLU."""
    extractor = CameraExtractor(gym.spaces.Box(0, 1, (1, 120, 160), np.float32), LEAN)
    images = camera_frames(8)
    assert torch.equal(extractor(images), plain_features(extractor, images))
    buffer = io.BytesIO()
    torch.save(extractor.state_dict(), buffer)
    assert "_last_conv" not in torch.load(io.BytesIO(buffer.getvalue()))
    assert isinstance(extractor.cnn[extractor._last_conv], nn.Conv2d)
