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
from tensorboard.compat.proto import attr_value_pb2, graph_pb2, node_def_pb2, types_pb2
from tensorboard.compat.proto.tensor_shape_pb2 import TensorShapeProto
from tensorboard.util import tensor_util

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
    """The numpy value of a ``Const`` node. Raises :class:`GraphError` for other nodes."""
    if node.op != "Const" or "value" not in node.attr:
        raise GraphError(f"{node.name} is a {node.op}, not a constant")
    try:
        return tensor_util.make_ndarray(node.attr["value"].tensor)
    except Exception as exc:  # a malformed TensorProto
        raise GraphError(f"{node.name}: unreadable constant ({exc})") from None
