"""The bounds an imported graph or checkpoint must fit, on the layouts real models use:
DeepRacer's Shape/StridedSlice/Pack flatten is measured before anything runs, and a
checkpoint's tensors are checked when the index is read and read only when used."""

from __future__ import annotations

import numpy as np
import pytest
from tensorboard.compat.proto import attr_value_pb2
from tensorboard.util import tensor_util

from tests.training.interchange.bomb_support import checkpoint_index, op
from training.interchange import tfcheckpoint, tfgraph
from training.interchange.graphbudget import check_graph
from training.interchange.tfcheckpoint import CheckpointFormatError, read_checkpoint
from training.interchange.tfgraph import GraphWriter, run_graph


def deepracer_flatten() -> GraphWriter:
    """``x [-1, 4, 4, 2]`` flattened the way DeepRacer's graphs do (the batch from Shape and
    StridedSlice, packed with the feature count), then a 32 → 8 dense layer."""
    writer = GraphWriter()
    writer.placeholder("x", [-1, 4, 4, 2])
    writer.graph.node.append(op("Shape", "shape", "x"))
    for name, value in (("begin", [0]), ("end", [1]), ("step", [1]), ("features", 32)):
        writer.const(name, np.int32(value))
    slice_ = op("StridedSlice", "batch", "shape", "begin", "end", "step")
    slice_.attr["shrink_axis_mask"].CopyFrom(attr_value_pb2.AttrValue(i=1))
    writer.graph.node.append(slice_)
    pack = op("Pack", "target", "batch", "features")
    pack.attr["axis"].CopyFrom(attr_value_pb2.AttrValue(i=0))
    writer.graph.node.append(pack)
    writer.graph.node.append(op("Reshape", "flat", "x", "target"))
    writer.const("w", np.arange(32 * 8, dtype=np.float32).reshape(32, 8) / 100)
    writer.graph.node.append(op("MatMul", "dense", "flat", "w", transpose_a=False))
    return writer


def test_deepracers_flatten_is_measured_before_anything_runs() -> None:
    graph = deepracer_flatten().graph
    cost = check_graph(graph)
    assert cost.macs_per_image == 32 * 8  # the Reshape's target was worked out
    assert (cost.nodes, cost.const_values) == (11, 4 + 32 * 8)
    images = np.random.default_rng(0).uniform(0, 1, (3, 4, 4, 2)).astype(np.float32)
    out = run_graph(graph, {"x": images}, "dense")
    weights = tensor_util.make_ndarray(graph.node[-2].attr["value"].tensor)
    np.testing.assert_allclose(out, images.reshape(3, 32) @ weights, rtol=1e-6)


def test_a_checkpoint_tensor_declaring_too_much_is_refused_before_any_is_read() -> None:
    index = checkpoint_index({"w": ([50_000_000], 0, 200_000_000)})
    with pytest.raises(CheckpointFormatError) as refused:
        read_checkpoint(index, {0: b""})
    assert str(refused.value) == (
        "the tensor 'w' declares 50,000,000 values; a DeepRacer model has at most 40,000,000 "
        "in one tensor (its biggest has 28,672,000)"
    )


def test_checkpoint_bytes_must_lie_in_the_shard() -> None:
    index = checkpoint_index({"w": ([4], 8, 16)})
    with pytest.raises(CheckpointFormatError, match="w: its bytes do not fit shape"):
        read_checkpoint(index, {0: bytes(16)})


def test_checkpoint_tensors_are_read_when_used_within_a_total(monkeypatch) -> None:
    shard = np.arange(8, dtype="<f4").tobytes()
    index = checkpoint_index({"a": ([4], 0, 16), "b": ([4], 16, 16), "c": ([2, 2], 0, 16)}, shard)
    tensors = read_checkpoint(index, {0: shard})
    assert sorted(tensors) == ["a", "b", "c"] and tensors._read == {}  # nothing read yet
    np.testing.assert_array_equal(tensors["b"], [4, 5, 6, 7])
    assert list(tensors._read) == ["b"]
    monkeypatch.setattr(tfcheckpoint, "MAX_GRAPH_VALUES", 6)
    with pytest.raises(CheckpointFormatError, match="more than 6 values in all .at 'c'."):
        tensors["c"]


def test_running_out_of_memory_is_not_mistaken_for_a_bad_constant(monkeypatch) -> None:
    """Under the child's memory limit, numpy's MemoryError must reach the child's handler
    (which words it as the memory limit), not become "unreadable constant"."""
    node = deepracer_flatten().graph.node[-2]

    def no_memory(tensor):
        raise MemoryError("Unable to allocate 109. MiB")

    monkeypatch.setattr(tfgraph.tensor_util, "make_ndarray", no_memory)
    with pytest.raises(MemoryError):
        tfgraph.const_value(node)
