"""What a frozen graph (``model.pb``) may declare and cost, checked before anything is built.

A ``GraphDef`` is a small file that can describe a lot: a constant stored as one value with a
shape of 50 million (a "fill", which numpy expands), two broadcast operands whose product is
huge, or a chain of MatMuls that costs minutes of CPU. :func:`check_graph` reads only the
declared shapes (and the values of tiny integer tensors, such as a Reshape's target) and
refuses a graph past any bound below, saying what and why; :func:`op_cost` is the same rule
for one op, which :func:`training.interchange.tfgraph.run_graph` applies again to the real
operands before it computes each op (shapes it could not know beforehand).

The bounds come from the biggest network Racecraft imports, DeepRacer's 5-layer CNN
(:data:`training.rl.policies.SPECS` ``DEEP_CONVOLUTIONAL_NETWORK``) on the 160x120 camera: its
convolutions leave 25x35x64 = 56,000 features, so its dense layer is 56,000 x 512 =
28,672,000 weights (115 MB as float32), about 28.8 M values in all with a stereo camera and a
LIDAR; one image costs about 126 M multiply-adds. Frozen policy graphs are small: Racecraft's
export of that network has 60 nodes, 28 deep; the AWS-trained 3-layer CNNs shipped with
deepracer-utils have 62 nodes, 27 deep, 5.8 M values and 22 M multiply-adds per image.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from tensorboard.compat.proto import graph_pb2, node_def_pb2, tensor_pb2
from tensorboard.util import tensor_util

LARGEST_REAL_TENSOR = 56_000 * 512
"""Values in the biggest tensor of a real DeepRacer model (the 5-layer CNN's dense kernel)."""
MAX_TENSOR_VALUES = 40_000_000
"""Values one tensor (a constant, or an op's result) may have: 1.4x the biggest real one."""
MAX_GRAPH_VALUES = 64_000_000
"""Values all the graph's constants may declare together: 2.2x the biggest real model (256 MB
as float32), so a graph that also kept its value network or a copy of it still fits."""
MAX_MACS_PER_IMAGE = 1_500_000_000
"""Multiply-adds of MatMul and Conv2D for one input image: about 12x the biggest real model."""
MAX_NODES = 2_000
"""Nodes in the graph: DeepRacer's frozen policies have about 60."""
MAX_DEPTH = 1_200
"""Longest chain of nodes, input to output: DeepRacer's are under 30 deep. (Nothing here
recurses, so the bound is about work, not the stack.)"""
MAX_RANK = 8
SMALL_VALUES = 64
"""Integer tensors up to this many values are read during the check (shapes, axes, slices)."""

Shape = tuple[int, ...]


class GraphBudgetError(ValueError):
    """A graph that declares or costs more than a DeepRacer model; the message says what."""


@dataclass(frozen=True)
class GraphCost:
    """What :func:`check_graph` counted: nodes, depth, constant values and multiply-adds per
    image (of the ops whose operand shapes are declared)."""

    nodes: int
    depth: int
    const_values: int
    macs_per_image: int


def declared_values(tensor: tensor_pb2.TensorProto, what: str) -> int:
    """Values a ``TensorProto`` declares (the product of its shape), whatever it stores.
    Raises :class:`GraphBudgetError` for an unknown or negative shape or one over
    :data:`MAX_TENSOR_VALUES`."""
    shape = tensor.tensor_shape
    if shape.unknown_rank or len(shape.dim) > MAX_RANK:
        raise GraphBudgetError(f"{what} has no usable shape ({len(shape.dim)} dimensions)")
    count = 1
    for dim in shape.dim:
        if dim.size < 0:
            raise GraphBudgetError(f"{what} declares a negative size ({dim.size})")
        count *= dim.size
    if count > MAX_TENSOR_VALUES:
        raise GraphBudgetError(
            f"{what} declares {count:,} values; a DeepRacer model has at most "
            f"{MAX_TENSOR_VALUES:,} in one tensor (its biggest has {LARGEST_REAL_TENSOR:,})"
        )
    return count


def _source(name: str) -> str:
    return name.split(":")[0].lstrip("^")


def _order(graph: graph_pb2.GraphDef) -> tuple[list[node_def_pb2.NodeDef], int]:
    """The nodes with every input before its consumers, and the graph's depth (without
    recursion, so a deep chain cannot exhaust the stack). Raises for a cycle."""
    nodes = {node.name: node for node in graph.node}
    depth: dict[str, int] = {}
    order: list[node_def_pb2.NodeDef] = []
    on_stack: set[str] = set()
    for root in nodes:
        if root in depth:
            continue
        stack = [(root, False)]
        while stack:
            name, expanded = stack.pop()
            if expanded:
                on_stack.discard(name)
                inputs = [_source(i) for i in nodes[name].input if _source(i) in nodes]
                depth[name] = 1 + max((depth[i] for i in inputs), default=0)
                if depth[name] > MAX_DEPTH:
                    raise GraphBudgetError(
                        f"the graph is more than {MAX_DEPTH:,} nodes deep (at {name!r}); "
                        "a DeepRacer model is under 30 deep"
                    )
                order.append(nodes[name])
                continue
            if name in depth:
                continue
            if name in on_stack:
                raise GraphBudgetError(f"the graph has a cycle through {name!r}")
            on_stack.add(name)
            stack.append((name, True))
            for source in nodes[name].input:
                source = _source(source)
                if source in nodes and source not in depth:
                    if source in on_stack:
                        raise GraphBudgetError(f"the graph has a cycle through {source!r}")
                    stack.append((source, False))
    return order, max(depth.values(), default=0)


def _count(shape: Shape | None) -> int:
    return int(np.prod(shape, dtype=object)) if shape is not None else 0


def _ints(node: node_def_pb2.NodeDef, key: str) -> list[int]:
    return [int(i) for i in node.attr[key].list.i]


def _window(node: node_def_pb2.NodeDef, key: str) -> tuple[int, int]:
    values = _ints(node, key)
    if len(values) != 4 or min(values) < 1:
        raise GraphBudgetError(f"{node.name}: {key} must be 4 positive numbers, not {values}")
    return values[1], values[2]


def _broadcast(node: node_def_pb2.NodeDef, shapes: Sequence[Shape | None]) -> Shape | None:
    if any(s is None for s in shapes):
        return None
    try:
        return tuple(int(d) for d in np.broadcast_shapes(*shapes))
    except ValueError:
        raise GraphBudgetError(
            f"{node.name}: the shapes {' and '.join(map(str, shapes))} do not broadcast"
        ) from None


def _matmul(node: node_def_pb2.NodeDef, a: Shape | None, b: Shape | None) -> tuple[Shape, int]:
    if a is None or b is None:
        return None, 0
    if len(a) != 2 or len(b) != 2:
        raise GraphBudgetError(f"{node.name}: MatMul takes matrices, not {a} and {b}")
    m, k = a[::-1] if node.attr["transpose_a"].b else a
    k2, n = b[::-1] if node.attr["transpose_b"].b else b
    if k != k2:
        raise GraphBudgetError(f"{node.name}: MatMul of shapes {a} and {b} does not fit")
    return (m, n), m * k * n


def _conv(node: node_def_pb2.NodeDef, x: Shape | None, kernel: Shape | None) -> tuple[Shape, int]:
    sh, sw = _window(node, "strides")
    if x is None or kernel is None:
        return None, 0
    if len(x) != 4 or len(kernel) != 4 or x[3] != kernel[2]:
        raise GraphBudgetError(f"{node.name}: Conv2D of shapes {x} and {kernel} does not fit")
    n, h, w, _ = x
    kh, kw, ci, co = kernel
    oh, ow = max(0, (h - kh) // sh + 1), max(0, (w - kw) // sw + 1)
    return (n, oh, ow, co), n * oh * ow * co * kh * kw * ci


def _reshape(node: node_def_pb2.NodeDef, x: Shape | None, target: np.ndarray | None) -> Shape:
    if x is None or target is None:
        return None
    dims = [int(d) for d in np.atleast_1d(target)]
    known = int(np.prod([d for d in dims if d != -1], dtype=object))
    if dims.count(-1) == 1 and known > 0:
        dims[dims.index(-1)] = _count(x) // known
    if dims.count(-1) or any(d < 0 for d in dims) or _count(tuple(dims)) != _count(x):
        raise GraphBudgetError(f"{node.name}: cannot reshape {x} to {target.tolist()}")
    return tuple(dims)


def strided_slice(
    x: np.ndarray, begin: np.ndarray, end: np.ndarray, node: node_def_pb2.NodeDef
) -> np.ndarray:
    """The one StridedSlice form frozen DeepRacer graphs use: a slice on axis 0, maybe
    shrinking it. Raises :class:`GraphBudgetError` for any other."""
    begin, end = np.atleast_1d(begin), np.atleast_1d(end)
    if len(begin) != 1 or len(end) != 1 or np.ndim(x) < 1:
        raise GraphBudgetError(f"{node.name}: unsupported StridedSlice")
    if node.attr["ellipsis_mask"].i or node.attr["new_axis_mask"].i:
        raise GraphBudgetError(f"{node.name}: unsupported StridedSlice")
    start = 0 if node.attr["begin_mask"].i & 1 else int(begin[0])
    stop = x.shape[0] if node.attr["end_mask"].i & 1 else int(end[0])
    return x[start] if node.attr["shrink_axis_mask"].i & 1 else x[start:stop]


def op_cost(
    node: node_def_pb2.NodeDef,
    shapes: Sequence[Shape | None],
    values: Sequence[np.ndarray | None],
) -> tuple[Shape | None, int]:
    """The result shape of ``node`` (None where it cannot be told) and its multiply-adds, from
    its operands' ``shapes`` and ``values`` (an operand's value when it is a small integer
    tensor, else None). Raises :class:`GraphBudgetError` for operands that do not fit
    the op or a result over :data:`MAX_TENSOR_VALUES`."""
    op, first = node.op, shapes[0] if shapes else None
    macs, shape = 0, None
    if op in ("Identity", "StopGradient", "Relu", "Tanh", "Softmax", "BiasAdd"):
        shape = first
    elif op in ("RealDiv", "Sub", "Mul", "Add", "AddV2", "Maximum", "Minimum"):
        shape = _broadcast(node, shapes[:2])
    elif op == "MatMul" and len(shapes) >= 2:
        shape, macs = _matmul(node, shapes[0], shapes[1])
    elif op == "Conv2D" and len(shapes) >= 2:
        shape, macs = _conv(node, shapes[0], shapes[1])
    elif op == "AvgPool":
        kh, kw = _window(node, "ksize")
        if first is not None and len(first) == 4:
            shape = (first[0], first[1] // kh, first[2] // kw, first[3])
    elif op == "Reshape" and len(shapes) >= 2:
        shape = _reshape(node, first, values[1])
    elif op == "Shape":
        shape = (len(first),) if first is not None else None
    elif op == "Pack" and shapes and all(s == first for s in shapes):
        shape = (len(shapes), *first) if first is not None else None
    elif op == "ConcatV2" and len(shapes) >= 3:
        axis, parts = values[len(shapes) - 1], shapes[:-1]
        if axis is not None and all(p is not None and len(p) == len(parts[0]) for p in parts):
            axis = int(np.asarray(axis).reshape(-1)[0]) % max(1, len(parts[0]))
            shape = (*parts[0][:axis], sum(p[axis] for p in parts), *parts[0][axis + 1 :])
    if shape is not None and _count(shape) > MAX_TENSOR_VALUES:
        raise GraphBudgetError(
            f"{node.name}: the op {op} would make {_count(shape):,} values; a DeepRacer model "
            f"has at most {MAX_TENSOR_VALUES:,} in one tensor"
        )
    return shape, macs


def _placeholder(node: node_def_pb2.NodeDef) -> Shape | None:
    shape = node.attr["shape"].shape
    if shape.unknown_rank or not shape.dim or len(shape.dim) > MAX_RANK:
        return None
    dims = tuple(1 if d.size == -1 else d.size for d in shape.dim)  # batch: one image
    return None if any(d < 0 for d in dims) else dims


def _small_value(node: node_def_pb2.NodeDef, shape: Shape | None, inputs: Sequence) -> object:
    """The value of a tiny integer tensor (a Const, or the Shape/StridedSlice/Pack plumbing
    that computes a Reshape target), else None."""
    op = node.op
    if op == "Const" and _count(shape) <= SMALL_VALUES:
        value = tensor_util.make_ndarray(node.attr["value"].tensor)
        return value if value.dtype.kind in "iu" else None
    if op == "Shape" and inputs[0][0] is not None:
        return np.asarray(inputs[0][0], np.int64)
    if op == "Identity":
        return inputs[0][1] if inputs else None
    if op == "StridedSlice" and len(inputs) >= 3 and all(v is not None for _, v in inputs[:3]):
        return strided_slice(inputs[0][1], inputs[1][1], inputs[2][1], node)
    if op == "Pack" and inputs and all(v is not None and np.ndim(v) == 0 for _, v in inputs):
        return np.stack([v for _, v in inputs])
    return None


def check_graph(graph: graph_pb2.GraphDef) -> GraphCost:
    """Refuse a graph past the module's bounds before any of it is built: node count, depth,
    each constant's declared values and their total, each op's result size and the
    multiply-adds of one image. Raises :class:`GraphBudgetError` saying what and why."""
    if len(graph.node) > MAX_NODES:
        raise GraphBudgetError(
            f"the graph has {len(graph.node):,} nodes; a DeepRacer model has at most {MAX_NODES:,}"
        )
    total = 0
    for node in graph.node:
        if node.op == "Const":
            total += declared_values(node.attr["value"].tensor, f"the constant {node.name!r}")
    if total > MAX_GRAPH_VALUES:
        raise GraphBudgetError(
            f"the graph's constants declare {total:,} values in all; a DeepRacer model has at "
            f"most {MAX_GRAPH_VALUES:,}"
        )
    order, depth = _order(graph)
    known: dict[str, tuple[Shape | None, object]] = {}
    macs = 0
    for node in order:
        inputs = [known.get(_source(i), (None, None)) for i in node.input if i[:1] != "^"]
        try:
            if node.op == "Const":
                shape = tuple(d.size for d in node.attr["value"].tensor.tensor_shape.dim)
            elif node.op == "Placeholder":
                shape = _placeholder(node)
            else:
                shape, cost = op_cost(node, [s for s, _ in inputs], [v for _, v in inputs])
                macs += cost
            known[node.name] = (shape, _small_value(node, shape, inputs))
        except GraphBudgetError:
            raise
        except (ValueError, IndexError, TypeError) as exc:  # a malformed tiny tensor
            raise GraphBudgetError(
                f"{node.name}: the op {node.op} cannot be read ({exc})"
            ) from None
        if macs > MAX_MACS_PER_IMAGE:
            raise GraphBudgetError(
                f"the graph needs more than {MAX_MACS_PER_IMAGE:,} multiply-adds per image "
                f"(at {node.name!r}, {macs:,}); a DeepRacer model needs at most about 126,000,000"
            )
    return GraphCost(len(graph.node), depth, total, macs)


def feeds_batch(feeds: Mapping[str, np.ndarray]) -> int:
    """The batch of ``feeds`` (the longest first axis), for the multiply-add budget."""
    return max((int(np.shape(v)[0]) for v in feeds.values() if np.ndim(v)), default=1)
