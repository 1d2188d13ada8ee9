"""Helpers for the car-model tests: frames, randomised tiny models, and the two real readers
of a frozen graph (TensorFlow, OpenVINO's TensorFlow front end)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from torch import nn

from training.interchange.export import BoxPolicy, DiscretePolicy, new_model
from training.rl.metadata import ModelMetadata, build_metadata

CONTINUOUS = {"steering_angle": {"low": -25.0, "high": 20.0}, "speed": {"low": 0.5, "high": 3.0}}
DISCRETE = [{"steering_angle": a, "speed": s} for a in (-30, -10, 0, 10, 30) for s in (1.0, 2.5)]


def metadata_for(network: str, sensor: str, algorithm: str) -> ModelMetadata:
    """``ppo_discrete``, ``ppo_continuous`` or ``sac`` for a network and a camera."""
    return build_metadata(
        action_space=DISCRETE if algorithm == "ppo_discrete" else CONTINUOUS,
        training_algorithm="sac" if algorithm == "sac" else "clipped_ppo",
        sensor=[sensor],
        neural_network=network,
    )


def randomised_model(metadata: ModelMetadata, seed: int) -> BaseAlgorithm:
    """A model whose every layer has fresh weights of unit gain (SB3 starts the heads near zero,
    which would make every action almost equally likely and the argmax meaningless)."""
    model = new_model(metadata)
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for module in model.policy.modules():
            if isinstance(module, nn.Linear | nn.Conv2d):
                fan_in = module.weight[0].numel()
                module.weight.normal_(0.0, 1.5 / fan_in**0.5, generator=generator)
                module.bias.normal_(0.0, 0.1, generator=generator)
    return model


def stereo(frames: np.ndarray) -> np.ndarray:
    """A stereo pair from mono frames: the right eye sees the scene 6 pixels to the left."""
    right = np.roll(frames, -6, axis=2)
    return np.concatenate([frames, right], axis=3)


def torch_outputs(
    model: BaseAlgorithm, frames_nhwc: np.ndarray, lidar: np.ndarray | None = None
) -> np.ndarray:
    """What the car graph must give: softmax probabilities, or the action in -1..1 (``lidar``:
    the LIDAR readings of a camera + LIDAR model, ``(n, size)``)."""
    discrete = hasattr(model.action_space, "n")
    wrapper = DiscretePolicy(model.policy) if discrete else BoxPolicy(model)
    readings = None if lidar is None else torch.as_tensor(lidar, dtype=torch.float32)
    with torch.no_grad():
        frames = torch.as_tensor(frames_nhwc.transpose(0, 3, 1, 2), dtype=torch.float32)
        out = wrapper(frames, readings)
    out = out.numpy()
    if discrete:
        return out
    low, high = model.action_space.low, model.action_space.high
    return 2.0 * (out - low) / (high - low) - 1.0


def run_tensorflow(
    graph: bytes, input_name: str, output_name: str, frames: np.ndarray
) -> np.ndarray:
    """Load the GraphDef in TensorFlow 1 mode and run it on float 0..255 NHWC frames."""
    tf = pytest.importorskip("tensorflow", reason="TensorFlow is in the [tf] test extra")
    graph_def = tf.compat.v1.GraphDef()
    graph_def.ParseFromString(graph)
    with tf.Graph().as_default() as g:
        tf.compat.v1.import_graph_def(graph_def, name="")
        # AWS-trained graphs pin their ops to /device:GPU:0; let TensorFlow place them on the CPU
        config = tf.compat.v1.ConfigProto(allow_soft_placement=True)
        with tf.compat.v1.Session(graph=g, config=config) as session:
            return session.run(f"{output_name}:0", {f"{input_name}:0": frames.astype(np.float32)})


# The car's Atom computes in 32-bit floats. OpenVINO's CPU plugin picks bfloat16 by itself on
# processors that have it (AVX-512 BF16, AMX), which moves outputs by ~3e-3: ask for f32, as the
# car gets.
CAR_PRECISION = {"INFERENCE_PRECISION_HINT": "f32"}


def run_openvino(path: str, input_name: str, frames: np.ndarray) -> np.ndarray:
    """Convert the .pb as the car does (input name, shape [1,120,160,C]) and infer frame by
    frame on the first output. Today's converter names TensorFlow inputs by tensor (``name:0``):
    it refuses the bare node name for DeepRacer's own AWS-trained graphs too."""
    ov = pytest.importorskip("openvino", reason="OpenVINO is in the dev extra")
    shape = [1, *frames.shape[1:]]
    converted = ov.convert_model(path, input=[(f"{input_name}:0", shape)])
    compiled = ov.Core().compile_model(converted, "CPU", CAR_PRECISION)
    output = compiled.output(0)
    return np.concatenate(
        [compiled(frame[None].astype(np.float32))[output] for frame in frames], axis=0
    )
