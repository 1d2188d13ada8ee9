"""A DeepRacer frozen graph (``model.pb``) read into the matching Racecraft torch policy.

The layers are read from the graph's ops between DeepRacer's input and output nodes
(:mod:`training.interchange.carmodel` names them): an optional input rescaling (``/255``,
``-offset``), an optional AvgPool, Conv2D + BiasAdd + Relu layers, a Reshape, MatMul + BiasAdd
layers, and the head (Softmax for discrete actions; for continuous ones the raw -1..1 output,
Racecraft's clip-and-rescale, or SAC's Tanh). DeepRacer's plumbing (Identity, StopGradient, the
gradient rescalers, Pack/StridedSlice) is skipped. The convolution stack picks the network of
:data:`training.rl.policies.SPECS`: a dense layer straight into the head is DeepRacer's layout
(``AWS_DEEPRACER_*``), a 64-unit hidden layer Racecraft's. Weights come only from Const nodes;
nothing is executed but numpy arithmetic. Finally the torch policy and the graph itself
(:func:`training.interchange.tfgraph.run_graph`) are run on probe images and must agree, so a
graph that computes something else is refused rather than imported wrong. With a LIDAR in the
metadata's sensors the graph must have Racecraft's camera + LIDAR layout (:func:`_read_lidar`).
Every weight read must be a finite number: a NaN or an infinity is refused naming its constant.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm

from training.interchange.carmodel import CAMERA_HEIGHT, CAMERA_WIDTH, input_name, output_name
from training.interchange.export import BoxPolicy, DiscretePolicy
from training.interchange.integrity import non_finite
from training.interchange.policybuild import (
    GraphImportError,
    Layer,
    NetworkLayers,
    build_policy,
    refusing_bad_values,
)
from training.interchange.tfgraph import GraphError, const_value, parse_graph, run_graph
from training.rl.metadata import ModelMetadata
from training.rl.policies import LIDAR_EMBEDDER_UNITS

__all__ = ["GraphImportError", "Layer", "NetworkLayers", "build_policy", "policy_from_graph"]

PROBE_TOLERANCE = 1e-4
PLUMBING = {
    "Identity",
    "StopGradient",
    "Pack",
    "StridedSlice",
    "Shape",
    "Sub",
    "Mul",
    "Add",
    "AddV2",
}


def _path_nodes(graph, source: str, target: str) -> list:
    """The nodes on some path from ``source`` to ``target``, in the graph's (topological)
    order. Raises :class:`GraphImportError` when either is missing or they are not joined."""
    nodes = {n.name: n for n in graph.node}
    for name, what in ((source, "input"), (target, "output")):
        if name not in nodes:
            raise GraphImportError(f"the graph has no {what} node {name}")
    upstream, stack = set(), [target]
    while stack:
        name = stack.pop()
        if name in upstream or name not in nodes:
            continue
        upstream.add(name)
        stack.extend(i.split(":")[0].lstrip("^") for i in nodes[name].input)
    if source not in upstream:
        raise GraphImportError(f"the output {target} does not depend on the input {source}")
    downstream = {source}
    for node in graph.node:  # frozen graphs list every input before its consumers
        if any(i.split(":")[0] in downstream for i in node.input):
            downstream.add(node.name)
    return [n for n in graph.node if n.name in upstream and n.name in downstream]


def _weight(nodes: dict, name: str) -> np.ndarray:
    """The Const behind ``name``, through Identity (``kernel/read``) nodes. Raises
    :class:`GraphImportError` when it is not a constant or holds a NaN or an infinity."""
    node = nodes[name.split(":")[0]]
    while node.op == "Identity":
        node = nodes[node.input[0].split(":")[0]]
    try:
        value = const_value(node).astype(np.float32)
    except GraphError as exc:
        raise GraphImportError(f"a weight is not a constant ({exc})") from None
    found = non_finite(value)
    if found is not None:
        raise GraphImportError(
            f"the constant {node.name!r} holds {found}; a model's weights must be finite numbers"
        )
    return value


def _read_layers(graph, source: str, target: str) -> NetworkLayers:
    nodes = {n.name: n for n in graph.node}
    path = _path_nodes(graph, source, target)
    on_path = {n.name for n in path}
    found = NetworkLayers()
    for node in path:
        op, layers = node.op, found.layers
        if node.name == source or (node.name == target and op == "ConcatV2"):
            continue  # a LIDAR branch is read up to the concatenation that joins it
        others = [i for i in node.input if i.split(":")[0] not in on_path]
        if op in ("RealDiv", "Mul", "Sub") and not layers and found.pool == 1 and others:
            value = float(_weight(nodes, others[0]).reshape(-1)[0])
            if op == "RealDiv":
                found.scale, found.offset = found.scale / value, found.offset / value
            elif op == "Mul":
                found.scale, found.offset = found.scale * value, found.offset * value
            else:
                found.offset -= value
        elif op == "AvgPool":
            found.pool = int(node.attr["ksize"].list.i[1])
        elif op == "Conv2D":
            if node.attr["padding"].s != b"VALID":
                raise GraphImportError(f"{node.name}: only VALID convolutions are supported")
            stride = int(node.attr["strides"].list.i[1])
            layers.append(Layer("conv", _weight(nodes, node.input[1]), stride))
        elif op == "MatMul":
            if node.attr["transpose_a"].b or node.attr["transpose_b"].b:
                raise GraphImportError(f"{node.name}: transposed MatMul is not supported")
            layers.append(Layer("dense", _weight(nodes, node.input[1])))
        elif op == "BiasAdd" and layers:
            layers[-1].bias = _weight(nodes, node.input[1])
        elif op in ("Relu", "Tanh") and layers and layers[-1].activation is None:
            layers[-1].activation = op
        elif op == "Softmax":
            found.head = "softmax"
        elif op == "ConcatV2":
            if found.concat is not None:
                raise GraphImportError(f"{node.name}: only one concatenation is supported")
            found.concat = (node.name, len(layers))
        elif op in ("Maximum", "Minimum"):
            found.head = "clip"
        elif op not in PLUMBING | {"Reshape"}:
            raise GraphImportError(f"{node.name}: the op {op} is not supported")
    if found.head == "linear" and found.layers and found.layers[-1].activation == "Tanh":
        found.layers[-1].activation, found.head = None, "tanh"
    return found


def _probe(model: BaseAlgorithm, graph, metadata: ModelMetadata, found: NetworkLayers) -> None:
    """Run the graph (numpy) and the torch policy on probe images; refuse if they differ."""
    rng = np.random.default_rng(0)
    images = rng.uniform(0, 255, (3, CAMERA_HEIGHT, CAMERA_WIDTH, metadata.channels)).astype(
        np.float32
    )
    images[0] = 0.0
    algorithm = metadata.training_algorithm
    feeds = {input_name(algorithm, metadata.camera): images}
    readings = None
    if metadata.lidar is not None:  # readings in the simulator's range (deepracer-spec §4)
        size = int(model.policy.observation_space.spaces[metadata.lidar].shape[0])
        feeds[input_name(algorithm, metadata.lidar)] = rng.uniform(0.15, 1.0, (3, size)).astype(
            np.float32
        )
        readings = torch.from_numpy(feeds[input_name(algorithm, metadata.lidar)])
    expected = run_graph(graph, feeds, output_name(algorithm))
    discrete = metadata.action_space_type == "discrete"
    wrapper = DiscretePolicy(model.policy) if discrete else BoxPolicy(model)
    with torch.no_grad():
        actual = wrapper(torch.from_numpy(images.transpose(0, 3, 1, 2).copy()), readings).numpy()
    if not discrete:  # the graph's actions are in -1..1 of the ranges
        low, high = model.action_space.low, model.action_space.high
        actual = 2.0 * (actual - low) / (high - low) - 1.0
        if found.head == "linear":  # the car clips DeepRacer's raw mean to -1..1
            expected = np.clip(expected, -1.0, 1.0)
    if expected.shape != actual.shape:
        raise GraphImportError(
            f"the graph's output has shape {expected.shape[1:]}, "
            f"the metadata's actions {actual.shape[1:]}"
        )
    error = float(np.abs(expected - actual).max())
    if not error <= PROBE_TOLERANCE * max(1.0, float(np.abs(expected).max())):
        raise GraphImportError(
            f"unsupported network: the imported policy differs from the graph by {error:.3g}"
        )


def _read_lidar(graph, found: NetworkLayers, metadata: ModelMetadata) -> None:
    """Read the LIDAR branch into ``found.lidar``: from the LIDAR input to the ConcatV2 that
    joins it after the camera's dense layer, as Racecraft's car export writes it
    (:mod:`training.interchange.carmodel`): dense 256 → 256 with ReLU
    (:data:`training.rl.policies.LIDAR_EMBEDDER_UNITS`), the camera's features first. Any
    other layout (DeepRacer's own joins the camera's flattened convolutions and the LIDAR
    before the 512-unit dense layer) is refused, naming what does not fit."""
    algorithm, lidar = metadata.training_algorithm, metadata.lidar
    if lidar is None:
        if found.concat is not None:
            raise GraphImportError(
                f"{found.concat[0]}: the graph joins a second input but the metadata's sensor "
                "list has no LIDAR"
            )
        return
    if found.concat is None:
        raise GraphImportError(
            f"unsupported network: the metadata lists a {lidar} but no LIDAR branch joins the "
            "camera's (no ConcatV2 between the camera input and the output)"
        )
    concat_name, before = found.concat
    nodes = {n.name: n for n in graph.node}
    branch = _read_layers(graph, input_name(algorithm, lidar), concat_name)
    joined = [i.split(":")[0] for i in nodes[concat_name].input]
    axis = _weight(nodes, joined[-1]).reshape(-1) if len(joined) == 3 else None
    lidar_side = {n.name for n in _path_nodes(graph, input_name(algorithm, lidar), concat_name)}
    if axis is None or int(axis[0]) not in (1, -1) or joined[1] not in lidar_side:
        raise GraphImportError(
            f"unsupported network: {concat_name} must join the camera's features and then the "
            "LIDAR's, along the features axis"
        )
    camera_denses = [layer.kind for layer in found.layers[:before]].count("dense")
    if camera_denses != 1:
        raise GraphImportError(
            f"unsupported network: the LIDAR joins the camera after {camera_denses} camera dense "
            "layers; Racecraft's camera + LIDAR network joins them after exactly one (the "
            "camera's own); DeepRacer's own layout, which joins them before its dense layer, "
            "cannot be imported"
        )
    units = [
        f"{layer.kind} {layer.kernel.shape[-1]} {layer.activation or 'linear'}"
        for layer in branch.layers
    ]
    embedder = [f"dense {n} Relu" for n in LIDAR_EMBEDDER_UNITS]
    if units != embedder or branch.pool != 1 or branch.head != "linear":
        raise GraphImportError(
            f"unsupported network: the LIDAR branch has layers {', '.join(units) or 'none'}; "
            f"Racecraft's LIDAR embedder is {', '.join(embedder)}"
        )
    # the branch's input is readings * scale + offset: fold that into the first dense layer
    first = branch.layers[0]
    bias = first.bias if first.bias is not None else np.zeros(first.kernel.shape[1], np.float32)
    first.bias = (bias + branch.offset * first.kernel.sum(axis=0)).astype(np.float32)
    first.kernel = (first.kernel * branch.scale).astype(np.float32)
    found.lidar = branch.layers


def policy_from_graph(data: bytes, metadata: ModelMetadata) -> tuple[BaseAlgorithm, ModelMetadata]:
    """The torch policy of a DeepRacer ``model.pb`` and the metadata naming its network.

    ``metadata`` is the archive's ``model_metadata.json`` (its sensor, algorithm and actions
    pick the tensor names and shapes). The graph's declared sizes and compute are checked
    first (:func:`~training.interchange.tfgraph.parse_graph`). Returns an SB3 model whose
    policy gives the graph's outputs (value function and SAC critics freshly initialised) and
    the metadata with ``neural_network`` set to the matching Racecraft network. Raises
    :class:`GraphImportError` naming the node, name or shape at fault, or the reason a
    malformed graph cannot be read.
    """
    try:
        graph = parse_graph(data)
    except GraphError as exc:
        raise GraphImportError(str(exc)) from None
    with refusing_bad_values("graph"):
        return _policy(graph, metadata)


def _policy(graph, metadata: ModelMetadata) -> tuple[BaseAlgorithm, ModelMetadata]:
    algorithm = metadata.training_algorithm
    found = _read_layers(graph, input_name(algorithm, metadata.camera), output_name(algorithm))
    _read_lidar(graph, found, metadata)
    if (found.head == "softmax") != (metadata.action_space_type == "discrete"):
        raise GraphImportError(
            f"the graph's head ({found.head}) does not fit a {metadata.action_space_type} "
            "action space"
        )
    squash = "tanh" if algorithm == "sac" else "linear"
    if metadata.action_space_type == "continuous" and found.head not in (squash, "clip"):
        raise GraphImportError(
            f"unsupported network: a {algorithm} graph whose head ends in {found.head}"
        )
    model, metadata = build_policy(found, metadata)
    try:
        _probe(model, graph, metadata, found)
    except GraphError as exc:
        raise GraphImportError(str(exc)) from None
    return model, metadata
