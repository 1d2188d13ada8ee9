"""A discrete policy's greedy choice in NumPy, for a worker that drives a whole evaluation itself.

An evaluation steps one car at a time. Driven from the trainer, each step costs a round trip to
the sandboxed worker (about 0.7 ms) and the trainer's torch inference for one frame (0.6-0.8
ms), beside the simulation's own 0.5 ms. Driven inside the worker, a step is the simulation
and this module's forward pass (about 0.15 ms for the lean network), and the trainer only
collects the outcome. The worker never imports torch (:mod:`training.rollout.hosted`), so the
network travels as a list of plain layers with NumPy weights, once per evaluation:
:func:`training.rollout.greedy.export_greedy` writes it from the policy, :class:`GreedyNet`
runs it.

The layers are those of the camera networks: average pooling, convolutions (no padding, one
group), dense layers, ReLU and tanh, and a flatten. Floats differ from torch's in the last
bits (another summation order), so where two actions' probabilities are within a rounding
error of each other the two can pick differently; the car's own runtime differs from torch in
the same way.
"""

from __future__ import annotations

from typing import Any

import numpy as np

OPS = frozenset({"pool", "conv", "dense", "relu", "tanh", "flatten"})
MAX_LAYERS = 64
MAX_WEIGHTS = 64 << 20
"""Floats a network may hold (256 MB): far beyond DeepRacer's largest (about 6 million)."""


class NetError(ValueError):
    """A network message that does not describe a network this module runs."""


def _array(value: Any, what: str, ndim: int) -> np.ndarray:
    if not isinstance(value, np.ndarray) or value.ndim != ndim or value.dtype != np.float32:
        raise NetError(f"{what}: expected a {ndim}-d float32 array")
    if not np.all(np.isfinite(value)):
        raise NetError(f"{what}: values must be finite")
    return value


def _patch_index(channels: int, height: int, width: int, kernel: int,
                 stride: int) -> tuple[np.ndarray, int, int]:  # fmt: skip
    """Flat indices into a (C, H, W) array of each output position's receptive field, one row
    per position (row-major over the output), in the (C, kh, kw) order of a conv weight."""
    out_h = (height - kernel) // stride + 1
    out_w = (width - kernel) // stride + 1
    if out_h < 1 or out_w < 1:
        raise NetError(f"a {kernel}×{kernel} convolution does not fit a {height}×{width} input")
    c, i, j = np.meshgrid(np.arange(channels), np.arange(kernel), np.arange(kernel),
                          indexing="ij")  # fmt: skip
    field = (c * height * width + i * width + j).reshape(-1)
    rows, cols = np.meshgrid(np.arange(out_h) * stride, np.arange(out_w) * stride, indexing="ij")
    starts = (rows * width + cols).reshape(-1, 1)
    return (starts + field[None, :]).astype(np.intp), out_h, out_w


class GreedyNet:
    """The policy network from its observation to its action logits, and the greedy action:
    the argmax of the softmax, as :func:`training.rollout.greedy.greedy_actions` picks it."""

    def __init__(self, layers: list[tuple], input_shape: tuple[int, int, int],
                 divisor: float) -> None:  # fmt: skip
        self.layers = layers
        self.input_shape = input_shape
        self.divisor = np.float32(divisor)
        self._plans: dict[tuple, list] = {}

    @classmethod
    def from_message(cls, message: Any) -> GreedyNet:
        """The network :func:`~training.rollout.greedy.export_greedy` described; raises
        :class:`NetError` for anything else."""
        if not isinstance(message, dict):
            raise NetError("a network must be a mapping")
        shape = message.get("input_shape")
        if (not isinstance(shape, list) or len(shape) != 3
                or not all(type(n) is int and 0 < n <= 4096 for n in shape)):  # fmt: skip
            raise NetError("input_shape: expected [channels, height, width]")
        divisor = message.get("divisor")
        if type(divisor) not in (int, float) or not np.isfinite(divisor) or divisor <= 0:
            raise NetError("divisor: expected a positive number")
        raw = message.get("layers")
        if not isinstance(raw, list) or not 0 < len(raw) <= MAX_LAYERS:
            raise NetError(f"layers: expected 1 to {MAX_LAYERS}")
        layers, weights = [], 0
        for n, layer in enumerate(raw):
            op = layer.get("op") if isinstance(layer, dict) else None
            if op not in OPS:
                raise NetError(f"layer {n}: unknown op {op!r}")
            if op == "pool":
                k = layer.get("kernel")
                if type(k) is not int or not 0 < k <= 64:
                    raise NetError(f"layer {n}: pooling kernel")
                layers.append(("pool", k))
            elif op == "conv":
                w = _array(layer.get("weight"), f"layer {n} weight", 4)
                b = _array(layer.get("bias"), f"layer {n} bias", 1)
                s = layer.get("stride")
                if w.shape[2] != w.shape[3] or b.shape[0] != w.shape[0]:
                    raise NetError(f"layer {n}: square kernels and one bias per filter")
                if type(s) is not int or not 0 < s <= 64:
                    raise NetError(f"layer {n}: stride")
                weights += w.size
                layers.append(("conv", w.reshape(w.shape[0], -1).T.copy(), b, w.shape[1],
                               w.shape[2], s))  # fmt: skip
            elif op == "dense":
                w = _array(layer.get("weight"), f"layer {n} weight", 2)
                b = _array(layer.get("bias"), f"layer {n} bias", 1)
                if b.shape[0] != w.shape[0]:
                    raise NetError(f"layer {n}: one bias per unit")
                weights += w.size
                layers.append(("dense", w.T.copy(), b))
            else:
                layers.append((op,))
            if weights > MAX_WEIGHTS:
                raise NetError(f"over {MAX_WEIGHTS:,} weights")
        net = cls(layers, (shape[0], shape[1], shape[2]), float(divisor))
        net.logits(np.zeros((1, shape[1], shape[2], shape[0]), np.uint8))  # shapes fit
        return net

    def _images(self, observations: np.ndarray) -> np.ndarray:
        """(N, C, H, W) float32 images, divided as SB3 normalises them, from channel-last or
        channel-first ones."""
        c, h, w = self.input_shape
        obs = np.asarray(observations)
        if obs.shape[1:] == (h, w, c):
            obs = obs.transpose(0, 3, 1, 2)
        elif obs.shape[1:] != (c, h, w):
            raise NetError(f"observations of shape {obs.shape[1:]}; the network takes {(c, h, w)}")
        return obs.astype(np.float32) / self.divisor

    def logits(self, observations: np.ndarray) -> np.ndarray:
        """Action logits for a batch of observations (as the envs give them)."""
        return np.stack([self._one(x) for x in self._images(observations)])

    def _one(self, x: np.ndarray) -> np.ndarray:
        for layer in self.layers:
            op = layer[0]
            if op == "pool":
                x = _pool(x, layer[1])
            elif op == "conv":
                _, w, b, channels, kernel, stride = layer
                if x.ndim != 3 or x.shape[0] != channels:
                    raise NetError(f"a convolution over {channels} channels got {x.shape}")
                key = (id(layer), x.shape)
                plan = self._plans.get(key)
                if plan is None:
                    plan = self._plans[key] = _patch_index(*x.shape, kernel, stride)
                index, out_h, out_w = plan
                x = (x.reshape(-1)[index] @ w + b).T.reshape(-1, out_h, out_w)
            elif op == "dense":
                _, w, b = layer
                if x.ndim != 1 or x.shape[0] != w.shape[0]:
                    raise NetError(f"a dense layer of {w.shape[0]} inputs got {x.shape}")
                x = x @ w + b
            elif op == "relu":
                x = np.maximum(x, np.float32(0))
            elif op == "tanh":
                x = np.tanh(x)
            else:
                x = x.reshape(-1)
        if x.ndim != 1:
            raise NetError("the network must end in a vector of action logits")
        return x

    def sample(self, observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """An action of each observation drawn from the softmax of its logits (a training
        car's choice, as SB3's categorical distribution draws it), with ``rng``."""
        logits = self.logits(observations).astype(np.float64)
        shifted = np.exp(logits - logits.max(axis=1, keepdims=True))
        cumulative = np.cumsum(shifted, axis=1)
        draws = rng.random(len(logits)) * cumulative[:, -1]
        chosen = (cumulative <= draws[:, None]).sum(axis=1)
        return np.minimum(chosen, logits.shape[1] - 1)

    def actions(self, observations: np.ndarray) -> np.ndarray:
        """The greedy action of each observation: argmax of the softmax (the first where two
        probabilities are equal)."""
        logits = self.logits(observations)
        shifted = np.exp(logits - logits.max(axis=1, keepdims=True))
        return (shifted / shifted.sum(axis=1, keepdims=True)).argmax(axis=1)


def _pool(x: np.ndarray, k: int) -> np.ndarray:
    """torch's ``AvgPool2d(k)`` of a (C, H, W) array: k×k blocks, the remainder dropped."""
    h, w = x.shape[1] // k, x.shape[2] // k
    total = None
    for i in range(k):
        for j in range(k):
            part = x[:, i : i + h * k : k, j : j + w * k : k]
            total = part.copy() if total is None else total + part
    return total * np.float32(1.0 / (k * k))
