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

GRAPH_PRODUCER = 27  # GraphDef version of TensorFlow 1.15, what DeepRacer's tools wrote
MAX_GRAPH_BYTES = 200 * 1024 * 1024
MAX_CONST_ELEMENTS = 50_000_000
"""Largest constant read (elements): a small file can declare a huge tensor of one repeated
value, which numpy would expand in memory."""


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
    """A ``GraphDef`` from ``model.pb`` bytes (at most 200 MB).

    Raises :class:`GraphError` when the bytes are too large or are not a GraphDef.
    """
    if len(data) > MAX_GRAPH_BYTES:
        raise GraphError(f"the graph is larger than {MAX_GRAPH_BYTES // (1024 * 1024)} MB")
    graph = graph_pb2.GraphDef()
    try:
        graph.ParseFromString(data)
    except Exception as exc:  # protobuf raises DecodeError and friends
        raise GraphError(f"not a TensorFlow GraphDef ({type(exc).__name__})") from None
    if not graph.node:
        raise GraphError("the graph has no nodes")
    return graph


def const_value(node: node_def_pb2.NodeDef) -> np.ndarray:
    """The numpy value of a ``Const`` node. Raises :class:`GraphError` for other nodes and for
    constants over :data:`MAX_CONST_ELEMENTS`."""
    if node.op != "Const" or "value" not in node.attr:
        raise GraphError(f"{node.name} is a {node.op}, not a constant")
    dims = [d.size for d in node.attr["value"].tensor.tensor_shape.dim]
    if any(d < 0 for d in dims) or int(np.prod(dims, dtype=np.float64)) > MAX_CONST_ELEMENTS:
        raise GraphError(f"{node.name}: a constant of shape {dims} is too large")
    try:
        return tensor_util.make_ndarray(node.attr["value"].tensor)
    except Exception as exc:  # a malformed TensorProto
        raise GraphError(f"{node.name}: unreadable constant ({exc})") from None


def _strided_slice(x: np.ndarray, begin: np.ndarray, end: np.ndarray, node) -> np.ndarray:
    """The one form frozen DeepRacer graphs use: a slice on axis 0, maybe shrinking it."""
    if len(begin) != 1 or node.attr["ellipsis_mask"].i or node.attr["new_axis_mask"].i:
        raise GraphError(f"{node.name}: unsupported StridedSlice")
    start = 0 if node.attr["begin_mask"].i & 1 else int(begin[0])
    stop = x.shape[0] if node.attr["end_mask"].i & 1 else int(end[0])
    return x[start] if node.attr["shrink_axis_mask"].i & 1 else x[start:stop]


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


def run_graph(graph: graph_pb2.GraphDef, feeds: dict[str, np.ndarray], output: str) -> np.ndarray:
    """Evaluate ``output`` of a small inference graph with numpy (float32), no TensorFlow.

    Covers the ops of DeepRacer's and Racecraft's policy graphs (those of :class:`GraphWriter`
    plus Identity, StopGradient, Shape, StridedSlice and Pack); ``feeds`` maps placeholder
    names to arrays. Raises :class:`GraphError` for any other op or a missing node.
    """
    nodes = {node.name: node for node in graph.node}
    values: dict[str, np.ndarray] = {}
    visiting: set[str] = set()

    def value(name: str) -> np.ndarray:
        name = name.split(":")[0]
        if name in values:
            return values[name]
        node = nodes.get(name)
        if node is None:
            raise GraphError(f"the graph has no node {name}")
        if name in visiting:
            raise GraphError(f"{name}: the graph has a cycle")
        visiting.add(name)
        args = [value(i) for i in node.input if not i.startswith("^")]
        op = node.op
        if op == "Placeholder":
            if name not in feeds:
                raise GraphError(f"no value fed for the input {name}")
            result = np.asarray(feeds[name], np.float32)
        elif op == "Const":
            result = const_value(node)
        elif op in ("Identity", "StopGradient"):
            result = args[0]
        elif op in _BINARY:
            result = _BINARY[op](args[0], args[1])
        elif op == "Relu":
            result = np.maximum(args[0], 0)
        elif op == "Tanh":
            result = np.tanh(args[0])
        elif op == "Softmax":
            result = _softmax(args[0])
        elif op == "MatMul":
            a, b = args
            a = a.T if node.attr["transpose_a"].b else a
            result = a @ (b.T if node.attr["transpose_b"].b else b)
        elif op == "Conv2D":
            result = _conv2d(*args, node)
        elif op == "AvgPool":
            result = _avg_pool(args[0], node)
        elif op == "Reshape":
            result = args[0].reshape([int(d) for d in np.atleast_1d(args[1])])
        elif op == "Shape":
            result = np.asarray(args[0].shape, np.int32)
        elif op == "StridedSlice":
            result = _strided_slice(args[0], args[1], args[2], node)
        elif op == "Pack":
            result = np.stack(args, axis=int(node.attr["axis"].i))
        elif op == "ConcatV2":
            result = np.concatenate(args[:-1], axis=int(np.asarray(args[-1]).reshape(-1)[0]))
        else:
            raise GraphError(f"{name}: the op {op} is not supported")
        values[name] = np.asarray(result)
        return values[name]

    return value(output)
