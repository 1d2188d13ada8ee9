"""GraphDef writing and reading without TensorFlow: the numpy evaluator and its guards."""

from __future__ import annotations

import numpy as np
import pytest
from tensorboard.compat.proto import attr_value_pb2, node_def_pb2, tensor_pb2, types_pb2
from tensorboard.compat.proto.tensor_shape_pb2 import TensorShapeProto

from tests.training.interchange.carmodel_support import (
    metadata_for,
    randomised_model,
    torch_outputs,
)
from training.interchange.carmodel import export_car_graph, input_name, output_name
from training.interchange.tfgraph import GraphError, const_value, parse_graph, run_graph
from training.rl.policies import LEAN


def test_numpy_evaluator_runs_the_car_graph(camera_frames) -> None:
    meta = metadata_for(LEAN, "FRONT_FACING_CAMERA", "ppo_continuous")
    model = randomised_model(meta, seed=5)
    graph = parse_graph(export_car_graph(model, meta))
    frames = camera_frames.astype(np.float32)
    out = run_graph(
        graph, {input_name("clipped_ppo", meta.camera): frames}, output_name("clipped_ppo")
    )
    np.testing.assert_allclose(out, torch_outputs(model, frames), atol=1e-4, rtol=0)


def test_a_huge_splatted_constant_is_refused() -> None:
    """Four bytes that declare two billion floats are not expanded."""
    shape = TensorShapeProto(dim=[TensorShapeProto.Dim(size=2_000_000_000)])
    tensor = tensor_pb2.TensorProto(dtype=types_pb2.DT_FLOAT, tensor_shape=shape, float_val=[1])
    node = node_def_pb2.NodeDef(name="bomb", op="Const")
    node.attr["value"].CopyFrom(attr_value_pb2.AttrValue(tensor=tensor))
    with pytest.raises(GraphError, match="the constant 'bomb' declares 2,000,000,000 values"):
        const_value(node)


def test_garbage_and_missing_nodes() -> None:
    with pytest.raises(GraphError, match="not a TensorFlow GraphDef"):
        parse_graph(b"\xff\xff\xff\xff not a protobuf")
    meta = metadata_for(LEAN, "FRONT_FACING_CAMERA", "ppo_discrete")
    graph = parse_graph(export_car_graph(randomised_model(meta, seed=1), meta))
    with pytest.raises(GraphError, match="no value fed for the input"):
        run_graph(graph, {}, output_name("clipped_ppo"))
    with pytest.raises(GraphError, match="the graph has no node nowhere"):
        run_graph(graph, {}, "nowhere")
