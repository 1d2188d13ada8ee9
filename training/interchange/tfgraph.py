"""Frozen TensorFlow 1 graphs (``GraphDef`` protobufs) written and read without TensorFlow.

The message classes and the numpy ↔ ``TensorProto`` conversion come from ``tensorboard``
(``tensorboard.compat.proto`` carries TensorFlow's own ``.proto`` definitions), so the console
can write and read the ``model.pb`` a DeepRacer car loads without installing TensorFlow.

:class:`GraphWriter` appends nodes in order (a frozen graph is a list of ``NodeDef``; every
input is named before it is used) and only offers ops that OpenVINO's TensorFlow front end and
TensorFlow Lite both convert: Placeholder, Const, RealDiv, Sub, Mul, Add, AvgPool, Conv2D,
BiasAdd, Relu, Tanh, Reshape, MatMul, Softmax, Minimum, Maximum. Tensors are float32, NHWC.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tensorboard.compat.proto import attr_value_pb2, graph_pb2, node_def_pb2, types_pb2
from tensorboard.compat.proto.tensor_shape_pb2 import TensorShapeProto
from tensorboard.util import tensor_util

from training.interchange.graphbudget import (
    MAX_MACS_PER_IMAGE,
    GraphBudgetError,
    check_graph,
    declared_values,
    feeds_batch,
    op_cost,
    strided_slice,
)

GRAPH_PRODUCER = 27  # GraphDef version of TensorFlow 1.15, what DeepRacer's tools wrote
MAX_GRAPH_BYTES = 200 * 1024 * 1024


class GraphError(ValueError):
    """A ``model.pb`` that does not parse, or lacks a node that should be there."""


def _attr(value: object) -> attr_value_pb2.AttrValue:
    if isinstance(value, bytes):
        return attr_value_pb2.AttrValue(s=value)
    if isinstance(value, bool):
        return attr_value_pb2.AttrValue(b=value)
    if isinstance(value, int):
        return attr_value_pb2.AttrValue(i=value)
    if isinstance(value, list):
        return attr_value_pb2.AttrValue(list=attr_value_pb2.AttrValue.ListValue(i=value))
    raise TypeError(f"no attribute of type {type(value).__name__}")


class GraphWriter:
    """Builds a float32 NHWC inference graph node by node; every method returns the node name."""

    def __init__(self) -> None:
        self.graph = graph_pb2.GraphDef()
        self.graph.versions.producer = GRAPH_PRODUCER

    def _node(self, op: str, name: str, inputs: Sequence[str], **attrs: object) -> str:
        node = node_def_pb2.NodeDef(op=op, name=name, input=list(inputs))
        for key, value in attrs.items():
            node.attr[key].CopyFrom(_attr(value))
        if op != "Const" and op != "Placeholder":
            node.attr["T"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_FLOAT))
        self.graph.node.append(node)
        return name

    def placeholder(self, name: str, shape: Sequence[int]) -> str:
        """An input; ``-1`` in ``shape`` is an unknown size (the batch)."""
        node = node_def_pb2.NodeDef(op="Placeholder", name=name)
        node.attr["dtype"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_FLOAT))
        dims = [TensorShapeProto.Dim(size=int(size)) for size in shape]
        node.attr["shape"].CopyFrom(attr_value_pb2.AttrValue(shape=TensorShapeProto(dim=dims)))
        self.graph.node.append(node)
        return name

    def const(self, name: str, value: np.ndarray | float | Sequence[int]) -> str:
        """A constant; floats are stored as float32, integer sequences as int32."""
        array = np.asarray(value)
        array = array.astype(np.int32 if array.dtype.kind in "iu" else np.float32)
        node = node_def_pb2.NodeDef(op="Const", name=name)
        dtype = types_pb2.DT_INT32 if array.dtype == np.int32 else types_pb2.DT_FLOAT
        node.attr["dtype"].CopyFrom(attr_value_pb2.AttrValue(type=dtype))
        tensor = tensor_util.make_tensor_proto(array)
        node.attr["value"].CopyFrom(attr_value_pb2.AttrValue(tensor=tensor))
        self.graph.node.append(node)
        return name

    def binary(self, op: str, name: str, x: str, y: str) -> str:
        """``RealDiv``, ``Sub``, ``Mul``, ``Add``, ``Minimum`` or ``Maximum`` of two nodes."""
        if op not in ("RealDiv", "Sub", "Mul", "Add", "Minimum", "Maximum"):
            raise ValueError(f"{op} is not an elementwise op of this writer")
        return self._node(op, name, [x, y])

    def unary(self, op: str, name: str, x: str) -> str:
        """``Relu``, ``Tanh`` or ``Softmax`` (over the last axis) of a node."""
        if op not in ("Relu", "Tanh", "Softmax"):
            raise ValueError(f"{op} is not an activation of this writer")
        return self._node(op, name, [x])

    def avg_pool(self, name: str, x: str, size: int) -> str:
        """``size``×``size`` average pooling with stride ``size``, no padding (NHWC)."""
        window = [1, size, size, 1]
        return self._node(
            "AvgPool", name, [x], ksize=window, strides=window, padding=b"VALID",
            data_format=b"NHWC",
        )  # fmt: skip

    def conv2d(
        self, name: str, x: str, kernel_hwio: np.ndarray, bias: np.ndarray, stride: int
    ) -> str:
        """``Conv2D`` (VALID padding) then ``BiasAdd``; ``kernel_hwio`` is [H, W, in, out]."""
        kernel = self.const(f"{name}/kernel", kernel_hwio)
        conv = self._node(
            "Conv2D", f"{name}/Conv2D", [x, kernel], strides=[1, stride, stride, 1],
            padding=b"VALID", data_format=b"NHWC", dilations=[1, 1, 1, 1],
        )  # fmt: skip
        return self._node(
            "BiasAdd", f"{name}/BiasAdd", [conv, self.const(f"{name}/bias", bias)],
            data_format=b"NHWC",
        )  # fmt: skip

    def dense(self, name: str, x: str, kernel_io: np.ndarray, bias: np.ndarray) -> str:
        """``MatMul`` then ``BiasAdd``; ``kernel_io`` is [in, out]."""
        matmul = self._node(
            "MatMul", f"{name}/MatMul", [x, self.const(f"{name}/kernel", kernel_io)],
            transpose_a=False, transpose_b=False,
        )  # fmt: skip
        return self._node(
            "BiasAdd", f"{name}/BiasAdd", [matmul, self.const(f"{name}/bias", bias)],
            data_format=b"NHWC",
        )  # fmt: skip

    def flatten(self, name: str, x: str, size: int) -> str:
        """``Reshape`` to ``[-1, size]``."""
        shape = self.const(f"{name}/shape", [-1, size])
        node = node_def_pb2.NodeDef(op="Reshape", name=name, input=[x, shape])
        node.attr["T"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_FLOAT))
        node.attr["Tshape"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_INT32))
        self.graph.node.append(node)
        return name

    def concat(self, name: str, xs: Sequence[str], axis: int = 1) -> str:
        """``ConcatV2`` of nodes along ``axis`` (the features of two sensors, side by side)."""
        axis_node = self.const(f"{name}/axis", np.int32(axis))  # a scalar, as TensorFlow wants
        node = node_def_pb2.NodeDef(op="ConcatV2", name=name, input=[*xs, axis_node])
        node.attr["T"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_FLOAT))
        node.attr["Tidx"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_INT32))
        node.attr["N"].CopyFrom(attr_value_pb2.AttrValue(i=len(xs)))
        self.graph.node.append(node)
        return name

    def serialize(self) -> bytes:
        return self.graph.SerializeToString(deterministic=True)


def parse_graph(data: bytes) -> graph_pb2.GraphDef:
    """A ``GraphDef`` from ``model.pb`` bytes (at most 200 MB), checked against the bounds of
    :mod:`training.interchange.graphbudget` (sizes, depth, compute) before anything is built.

    Raises :class:`GraphError` when the bytes are too large, are not a GraphDef, or declare
    more than a DeepRacer model (the message says what).
    """
    if len(data) > MAX_GRAPH_BYTES:
        raise GraphError(f"the graph is larger than {MAX_GRAPH_BYTES // (1024 * 1024)} MB")
    graph = graph_pb2.GraphDef()
    try:
        graph.ParseFromString(data)
    except MemoryError:  # the import's memory limit, reported as such
        raise
    except Exception as exc:  # protobuf raises DecodeError and friends
        raise GraphError(f"not a TensorFlow GraphDef ({type(exc).__name__})") from None
    if not graph.node:
        raise GraphError("the graph has no nodes")
    try:
        check_graph(graph)
    except GraphBudgetError as exc:
        raise GraphError(str(exc)) from None
    return graph


def const_value(node: node_def_pb2.NodeDef) -> np.ndarray:
    """The numpy value of a ``Const`` node. Raises :class:`GraphError` for other nodes and for
    constants declaring over :data:`~training.interchange.graphbudget.MAX_TENSOR_VALUES`
    values (checked before any is built)."""
    if node.op != "Const" or "value" not in node.attr:
        raise GraphError(f"{node.name} is a {node.op}, not a constant")
    try:
        declared_values(node.attr["value"].tensor, f"the constant {node.name!r}")
    except GraphBudgetError as exc:
        raise GraphError(str(exc)) from None
    try:
        return tensor_util.make_ndarray(node.attr["value"].tensor)
    except MemoryError:  # the import's memory limit, reported as such
        raise
    except Exception as exc:  # a malformed TensorProto
        raise GraphError(f"{node.name}: unreadable constant ({exc})") from None


def _conv2d(x: np.ndarray, kernel: np.ndarray, node) -> np.ndarray:
    stride = list(node.attr["strides"].list.i)
    if node.attr["padding"].s != b"VALID" or node.attr["data_format"].s not in (b"", b"NHWC"):
        raise GraphError(f"{node.name}: only VALID, NHWC convolutions are supported")
    out = torch.nn.functional.conv2d(
        torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2))),
        torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1))),
        stride=(stride[1], stride[2]),
    )
    return out.numpy().transpose(0, 2, 3, 1)


def _avg_pool(x: np.ndarray, node) -> np.ndarray:
    size, stride = list(node.attr["ksize"].list.i), list(node.attr["strides"].list.i)
    if size != stride or size[0] != 1 or size[3] != 1 or size[1] != size[2]:
        raise GraphError(f"{node.name}: only square, non-overlapping pooling is supported")
    k = size[1]
    n, h, w, c = x.shape
    x = x[:, : h // k * k, : w // k * k]
    return x.reshape(n, h // k, k, w // k, k, c).mean(axis=(2, 4))


_BINARY = {
    "RealDiv": np.divide,
    "Sub": np.subtract,
    "Mul": np.multiply,
    "Add": np.add,
    "AddV2": np.add,
    "Maximum": np.maximum,
    "Minimum": np.minimum,
    "BiasAdd": np.add,
}


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def _compute(node: node_def_pb2.NodeDef, args: list[np.ndarray]) -> np.ndarray:
    """One op of :func:`run_graph` on its evaluated operands."""
    op = node.op
    if op == "Const":
        return const_value(node)
    if op in ("Identity", "StopGradient"):
        return args[0]
    if op in _BINARY:
        return _BINARY[op](args[0], args[1])
    if op == "Relu":
        return np.maximum(args[0], 0)
    if op == "Tanh":
        return np.tanh(args[0])
    if op == "Softmax":
        return _softmax(args[0])
    if op == "MatMul":
        a, b = args
        a = a.T if node.attr["transpose_a"].b else a
        return a @ (b.T if node.attr["transpose_b"].b else b)
    if op == "Conv2D":
        return _conv2d(*args, node)
    if op == "AvgPool":
        return _avg_pool(args[0], node)
    if op == "Reshape":
        return args[0].reshape([int(d) for d in np.atleast_1d(args[1])])
    if op == "Shape":
        return np.asarray(args[0].shape, np.int32)
    if op == "StridedSlice":
        return strided_slice(args[0], args[1], args[2], node)
    if op == "Pack":
        return np.stack(args, axis=int(node.attr["axis"].i))
    if op == "ConcatV2":
        return np.concatenate(args[:-1], axis=int(np.asarray(args[-1]).reshape(-1)[0]))
    raise GraphError(f"{node.name}: the op {op} is not supported")


def _small(array: np.ndarray) -> np.ndarray | None:
    return array if array.dtype.kind in "iu" and array.size <= 64 else None


def run_graph(graph: graph_pb2.GraphDef, feeds: dict[str, np.ndarray], output: str) -> np.ndarray:
    """Evaluate ``output`` of a small inference graph with numpy (float32), no TensorFlow.

    Covers the ops of DeepRacer's and Racecraft's policy graphs (those of :class:`GraphWriter`
    plus Identity, StopGradient, Shape, StridedSlice and Pack); ``feeds`` maps placeholder
    names to arrays. Before each op runs, its result size and multiply-adds are checked on the
    real operands (:func:`~training.interchange.graphbudget.op_cost`; at most
    :data:`~training.interchange.graphbudget.MAX_MACS_PER_IMAGE` per fed image). Raises
    :class:`GraphError` for any other op, a missing node, a cycle, an op past those bounds or
    operands it cannot compute (naming the node and the reason).
    """
    try:
        check_graph(graph)
    except GraphBudgetError as exc:
        raise GraphError(str(exc)) from None
    nodes = {node.name: node for node in graph.node}
    budget = MAX_MACS_PER_IMAGE * feeds_batch(feeds)
    values: dict[str, np.ndarray] = {}
    spent = 0
    stack = [output.split(":")[0]]
    while stack:  # depth-first without recursion: inputs first, then the node itself
        name = stack[-1]
        if name in values:
            stack.pop()
            continue
        node = nodes.get(name)
        if node is None:
            raise GraphError(f"the graph has no node {name}")
        inputs = [i.split(":")[0] for i in node.input if not i.startswith("^")]
        missing = [i for i in inputs if i not in values]
        if missing:  # check_graph refused cycles, so this ends
            stack.extend(missing)
            continue
        stack.pop()
        args = [values[i] for i in inputs]
        if node.op == "Placeholder":
            if name not in feeds:
                raise GraphError(f"no value fed for the input {name}")
            values[name] = np.asarray(feeds[name], np.float32)
            continue
        try:
            _, cost = op_cost(node, [a.shape for a in args], [_small(a) for a in args])
            spent += cost
            if spent > budget:
                raise GraphError(
                    f"{name}: the graph needs more than {budget:,} multiply-adds for "
                    f"{budget // MAX_MACS_PER_IMAGE} images; a DeepRacer model needs at most "
                    "about 126,000,000 per image"
                )
            values[name] = np.asarray(_compute(node, args))
        except GraphError:
            raise
        except GraphBudgetError as exc:
            raise GraphError(str(exc)) from None
        except (ValueError, IndexError, TypeError, ZeroDivisionError, RuntimeError) as exc:
            if "can't allocate memory" in str(exc):  # torch's allocator at the memory limit
                raise MemoryError(str(exc)) from None
            raise GraphError(f"{name}: the op {node.op} cannot be computed ({exc})") from None
    return values[output.split(":")[0]]
