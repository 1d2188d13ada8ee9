"""A DeepRacer TensorFlow checkpoint read into the matching Racecraft torch policy.

A checkpoint holds variables, not the graph: its tensors are laid out as
:mod:`training.interchange.graphimport` reads a graph's layers and built the same way. Every
tensor the policy is built from must hold finite numbers (:class:`FiniteTensors`).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm

from training.interchange.carmodel import output_name
from training.interchange.integrity import non_finite
from training.interchange.policybuild import (
    GraphImportError,
    Layer,
    NetworkLayers,
    build_policy,
    refusing_bad_values,
)
from training.interchange.tfcheckpoint import CheckpointFormatError
from training.rl.metadata import ModelMetadata
from training.rl.policies import SPECS


class FiniteTensors(Mapping[str, np.ndarray]):
    """A checkpoint's tensors, each refused when it is read if it holds a NaN or an infinity
    (:class:`GraphImportError` naming the tensor); the tensors never read are not looked at."""

    def __init__(self, tensors: Mapping[str, np.ndarray]) -> None:
        self._tensors = tensors

    def __getitem__(self, name: str) -> np.ndarray:
        array = self._tensors[name]
        found = non_finite(array)
        if found is not None:
            raise GraphImportError(
                f"the tensor {name!r} holds {found}; a model's weights must be finite numbers"
            )
        return array

    def __contains__(self, name: object) -> bool:
        return name in self._tensors

    def __iter__(self) -> Iterator[str]:
        return iter(self._tensors)

    def __len__(self) -> int:
        return len(self._tensors)


def policy_from_checkpoint(
    tensors: Mapping[str, np.ndarray], metadata: ModelMetadata
) -> tuple[BaseAlgorithm, ModelMetadata]:
    """The torch policy of a DeepRacer TensorFlow checkpoint (tensors by variable name, see
    :mod:`training.interchange.tfcheckpoint`), as :func:`policy_from_graph` gives it.

    A checkpoint holds variables, not the graph, so DeepRacer's layout is assumed: the policy
    network's ``<SENSOR>/Conv2d_<n>/kernel|bias`` (strides from the matching network of
    :data:`training.rl.policies.SPECS`), ``middleware_fc_embedder/Dense_0`` and the one dense
    layer of its head, on images divided by 255. Raises :class:`GraphImportError` (for a
    malformed tensor too, with the reason, and for a tensor read that holds a NaN or an
    infinity), or :class:`CheckpointFormatError` (a tensor that fails its checksum).
    """
    with refusing_bad_values("checkpoint", passing=(CheckpointFormatError,)):
        return _policy(FiniteTensors(tensors), metadata)


def _policy(
    tensors: Mapping[str, np.ndarray], metadata: ModelMetadata
) -> tuple[BaseAlgorithm, ModelMetadata]:
    if metadata.lidar is not None:
        raise GraphImportError(
            f"importing a DeepRacer checkpoint with a {metadata.lidar} is not supported: its "
            "LIDAR embedder is not mapped (only camera and stereo-camera checkpoints are)"
        )
    algorithm = metadata.training_algorithm
    scope = output_name(algorithm).rsplit("/", 2)[0] + "/"
    head_scope = output_name(algorithm).rsplit("/", 1)[0] + "/"
    convs = {}
    for name in tensors:
        match = re.fullmatch(rf"{re.escape(scope + metadata.camera)}/Conv2d_(\d+)/kernel", name)
        if match:
            convs[int(match.group(1))] = name[: -len("kernel")]
    if not convs:
        raise GraphImportError(f"no convolution under {scope}{metadata.camera}/ in the checkpoint")
    for name in tensors:  # DeepRacer's 5-layer network: a 64→64 dense on every pixel
        if re.fullmatch(rf"{re.escape(scope + metadata.camera)}/Dense_\d+/kernel", name):
            raise GraphImportError(
                f"unsupported network: {name} is a dense layer on every pixel of the last "
                "convolution (DeepRacer's 5-layer CNN has one), which no Racecraft network has"
            )
    kernels = [tensors[convs[i] + "kernel"] for i in sorted(convs)]
    shapes = [(int(k.shape[3]), int(k.shape[0])) for k in kernels]
    strides = next(
        (
            [s for _, _, s in spec]
            for _, spec, _ in SPECS.values()
            if [(f, k) for f, k, _ in spec] == shapes
        ),
        None,
    )
    if strides is None:
        raise GraphImportError(f"unsupported network: convolutions (filters, kernel) {shapes}")
    found = NetworkLayers(
        scale=1 / 255.0, head="softmax" if metadata.action_space_type == "discrete" else "linear"
    )
    if algorithm == "sac":
        found.head = "tanh"
    for i, kernel, stride in zip(sorted(convs), kernels, strides, strict=True):
        found.layers.append(Layer("conv", kernel, stride, tensors.get(convs[i] + "bias"), "Relu"))
    heads = [n for n in tensors if n.startswith(head_scope) and n.endswith("/kernel")]
    dense = scope + "middleware_fc_embedder/Dense_0/"
    if dense + "kernel" not in tensors or len(heads) != 1:
        raise GraphImportError(
            f"the checkpoint needs {dense}kernel and one kernel under {head_scope} "
            f"(found {len(heads)})"
        )
    found.layers.append(
        Layer("dense", tensors[dense + "kernel"], 1, tensors.get(dense + "bias"), "Relu")
    )
    head = heads[0][: -len("kernel")]
    found.layers.append(Layer("dense", tensors[head + "kernel"], 1, tensors.get(head + "bias")))
    return build_policy(found, metadata)
