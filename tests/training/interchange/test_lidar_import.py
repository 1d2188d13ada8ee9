"""Importing car models with a LIDAR: a camera (or stereo) + LIDAR model exported for the car
imports back into the same MultiInputPolicy and gives the graph's outputs; a graph whose LIDAR
branch is not Racecraft's (DeepRacer's own layout among them) is refused, saying why."""

from __future__ import annotations

import json

import numpy as np
import pytest
from torch import nn

from tests.training.interchange.carmodel_support import (
    CONTINUOUS,
    DISCRETE,
    randomised_model,
    stereo,
    torch_outputs,
)
from training.interchange.archive import ArchiveError
from training.interchange.carmodel import (
    build_car_archive,
    car_metadata,
    export_car_graph,
    input_name,
    output_name,
)
from training.interchange.checkpointimport import policy_from_checkpoint
from training.interchange.deepracer import import_car_archive
from training.interchange.export import load_checkpoint
from training.interchange.graphimport import GraphImportError
from training.interchange.tarball import deterministic_tar_gz as tar_gz
from training.interchange.tfgraph import GraphWriter, parse_graph, run_graph
from training.rl.metadata import build_metadata
from training.rl.policies import AWS_SHALLOW, LEAN, SHALLOW, SPECS

CASES = [
    ("clipped_ppo", DISCRETE, "FRONT_FACING_CAMERA", "LIDAR", 64, LEAN),
    ("clipped_ppo", CONTINUOUS, "STEREO_CAMERAS", "SECTOR_LIDAR", 8, AWS_SHALLOW),
    ("sac", CONTINUOUS, "FRONT_FACING_CAMERA", "DISCRETIZED_SECTOR_LIDAR", 64, LEAN),
]
IDS = ["ppo-discrete-lidar", "ppo-continuous-stereo-sector-aws", "sac-discretized"]


def inputs(camera: str, size: int, n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random NHWC 0..255 frames and LIDAR readings."""
    rng = np.random.default_rng(size + n)
    frames = rng.integers(0, 256, (n, 120, 160, 1)).astype(np.float32)
    if camera == "STEREO_CAMERAS":
        frames = stereo(frames)
    return frames, rng.uniform(0.0, 1.0, (n, size)).astype(np.float32)


@pytest.mark.parametrize("algorithm, actions, camera, lidar, size, network", CASES, ids=IDS)
def test_exported_lidar_car_model_imports_and_drives_as_the_graph(
    algorithm, actions, camera, lidar, size, network
) -> None:
    meta = build_metadata(action_space=actions, training_algorithm=algorithm,
                          sensor=[camera, lidar], neural_network=network)  # fmt: skip
    model = randomised_model(meta, seed=size)
    graph = export_car_graph(model, meta)
    imported = import_car_archive(build_car_archive(meta, model))
    assert (imported.metadata.neural_network, tuple(imported.metadata.sensor)) == (
        network,
        (camera, lidar),
    )
    frames, readings = inputs(camera, size)
    feeds = {input_name(algorithm, camera): frames, input_name(algorithm, lidar): readings}
    expected = run_graph(parse_graph(graph), feeds, output_name(algorithm))
    again = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    actual = torch_outputs(again, frames, readings)
    np.testing.assert_allclose(actual, expected, atol=1e-4, rtol=0)
    if actions is DISCRETE:
        assert (actual.argmax(axis=1) == expected.argmax(axis=1)).all()
    # it drives: SB3 takes the simulator's observation (HWC uint8 image + LIDAR vector)
    action, _ = again.predict(
        {camera: frames[0].astype(np.uint8), lidar: readings[0]}, deterministic=True
    )
    assert again.action_space.contains(np.asarray(action, dtype=again.action_space.dtype))


def rescaled_lidar(graph_bytes: bytes, lidar_input: str) -> bytes:
    """The graph with ``readings * 0.5 - 0.1`` between the LIDAR input and its first layer."""
    graph, w = parse_graph(graph_bytes), GraphWriter()
    x = w.binary("Mul", "lidar_scale", lidar_input, w.const("lidar_scale/y", 0.5))
    w.binary("Sub", "lidar_offset", x, w.const("lidar_offset/y", 0.1))
    nodes = []
    for node in graph.node:
        if lidar_input in node.input:
            node.input[list(node.input).index(lidar_input)] = "lidar_offset"
        nodes.append(node)
        if node.name == lidar_input:  # inputs stay listed before their consumers
            nodes.extend(w.graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    return graph.SerializeToString()


def test_a_rescaled_lidar_input_is_folded_into_the_first_layer() -> None:
    meta = build_metadata(action_space=DISCRETE, sensor=["FRONT_FACING_CAMERA", "SECTOR_LIDAR"],
                          neural_network=LEAN)  # fmt: skip
    lidar = input_name("clipped_ppo", "SECTOR_LIDAR")
    graph = rescaled_lidar(export_car_graph(randomised_model(meta, seed=7), meta), lidar)
    files = {"model_metadata.json": car_metadata(meta), "agent/model.pb": graph}
    imported = import_car_archive(tar_gz(files))
    frames, readings = inputs("FRONT_FACING_CAMERA", 8)
    feeds = {input_name("clipped_ppo", "FRONT_FACING_CAMERA"): frames, lidar: readings}
    expected = run_graph(parse_graph(graph), feeds, output_name("clipped_ppo"))
    actual = torch_outputs(load_checkpoint(imported.checkpoint_bytes, imported.metadata),
                           frames, readings)  # fmt: skip
    np.testing.assert_allclose(actual, expected, atol=1e-4, rtol=0)


def deepracer_layout() -> bytes:
    """A graph laid out as DeepRacer joins a camera and a LIDAR: the flattened convolutions and
    the LIDAR embedder concatenated *before* the 512-unit dense layer."""
    rng = np.random.default_rng(0)
    w, scope = GraphWriter(), "main_level/agent/main/online/network_1"

    def dense(name: str, x: str, n_in: int, n_out: int) -> str:
        return w.dense(name, x, rng.normal(0, 0.1, (n_in, n_out)), np.zeros(n_out))

    x = w.placeholder(input_name("clipped_ppo", "FRONT_FACING_CAMERA"), [-1, 120, 160, 1])
    x = w.binary("RealDiv", f"{scope}/camera/truediv", x, w.const(f"{scope}/camera/y", 255.0))
    h, wd, c = 120, 160, 1
    for i, (filters, k, s) in enumerate(SPECS[SHALLOW][1]):
        kernel = rng.normal(0, 0.1, (k, k, c, filters))
        x = w.unary("Relu", f"{scope}/relu_{i}", w.conv2d(f"{scope}/conv_{i}", x, kernel,
                                                          np.zeros(filters), s))  # fmt: skip
        h, wd, c = (h - k) // s + 1, (wd - k) // s + 1, filters
    x = w.flatten(f"{scope}/flatten", x, h * wd * c)
    y = w.placeholder(input_name("clipped_ppo", "LIDAR"), [-1, 64])
    y = w.unary("Relu", f"{scope}/LIDAR/relu_0", dense(f"{scope}/LIDAR/Dense_0", y, 64, 256))
    y = w.unary("Relu", f"{scope}/LIDAR/relu_1", dense(f"{scope}/LIDAR/Dense_1", y, 256, 256))
    x = w.concat(f"{scope}/merger", [x, y])
    x = w.unary("Relu", f"{scope}/fc_relu", dense(f"{scope}/fc", x, h * wd * c + 256, 512))
    logits = dense(f"{scope}/ppo_head_0/policy_fc", x, 512, len(DISCRETE))
    w.unary("Softmax", output_name("clipped_ppo"), logits)
    return w.serialize()


def test_unrecognised_lidar_branches_are_refused_in_plain_words() -> None:
    meta = build_metadata(action_space=DISCRETE, sensor=["FRONT_FACING_CAMERA", "LIDAR"],
                          neural_network=LEAN)  # fmt: skip
    files = {"model_metadata.json": car_metadata(meta)}
    model = randomised_model(meta, seed=4)
    model.policy.features_extractor.lidar = nn.Sequential(nn.Linear(64, 256), nn.ReLU())
    one_layer = {**files, "agent/model.pb": export_car_graph(model, meta)}
    refusal = "LIDAR branch has layers dense 256 Relu; Racecraft's LIDAR embedder is dense 256"
    with pytest.raises(ArchiveError, match=refusal):
        import_car_archive(tar_gz(one_layer))
    aws = {**files, "agent/model.pb": deepracer_layout()}
    with pytest.raises(ArchiveError, match="after 0 camera dense layers; .*DeepRacer's own layout"):
        import_car_archive(tar_gz(aws))
    camera_only = build_metadata(action_space=DISCRETE, neural_network=LEAN)
    no_branch = {**files, "agent/model.pb": export_car_graph(randomised_model(camera_only, 1),
                                                             camera_only)}  # fmt: skip
    with pytest.raises(ArchiveError, match="lists a LIDAR but no LIDAR branch joins"):
        import_car_archive(tar_gz(no_branch))
    without = json.loads(one_layer["model_metadata.json"]) | {"sensor": ["FRONT_FACING_CAMERA"]}
    lidar_graph = {**files, "agent/model.pb": export_car_graph(randomised_model(meta, 2), meta)}
    with pytest.raises(ArchiveError, match="joins a second input but the metadata's sensor"):
        import_car_archive(tar_gz({**lidar_graph, "model_metadata.json": json.dumps(without)
                                   .encode()}))  # fmt: skip
    # a TensorFlow checkpoint holds no graph to check a LIDAR branch against: refused
    with pytest.raises(GraphImportError, match="checkpoint with a LIDAR is not supported"):
        policy_from_checkpoint({}, meta)
