"""The car download: a frozen TensorFlow graph with DeepRacer's names, checked by the readers a
car and DeepRacer's tools use (OpenVINO's TensorFlow front end, TensorFlow itself)."""

from __future__ import annotations

import io
import json
import tarfile

import numpy as np
import pytest

from tests.training.interchange.carmodel_support import (
    metadata_for,
    randomised_model,
    run_openvino,
    run_tensorflow,
    stereo,
    torch_outputs,
)
from training.interchange.carmodel import (
    RACECRAFT_NETWORK_KEY,
    build_car_archive,
    export_car_graph,
    input_name,
    output_name,
)
from training.interchange.export import ARCHIVE_MTIME, checkpoint_bytes
from training.interchange.tfgraph import parse_graph
from training.rl.policies import AWS_SHALLOW, COMPACT, LEAN, SHALLOW, STANDARD

ALGORITHMS = ["ppo_discrete", "ppo_continuous", "sac"]
SENSORS = ["FRONT_FACING_CAMERA", "STEREO_CAMERAS"]


@pytest.fixture(scope="module")
def frames(camera_frames) -> np.ndarray:
    """100 float 0..255 NHWC camera frames: 20 from the simulator, 80 darkened/brightened."""
    base = camera_frames.astype(np.float32)
    gains = np.linspace(0.6, 1.4, 5)
    varied = np.concatenate([np.clip(base * g, 0, 255) for g in gains[:4]] + [base])
    return varied[:100]


def frames_for(sensor: str, frames: np.ndarray) -> np.ndarray:
    return stereo(frames) if sensor == "STEREO_CAMERAS" else frames


def assert_agree(actual: np.ndarray, expected: np.ndarray, discrete: bool) -> None:
    np.testing.assert_allclose(actual, expected, atol=1e-3, rtol=0)
    if discrete:
        assert (actual.argmax(axis=1) == expected.argmax(axis=1)).all()


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("network", [COMPACT, LEAN, SHALLOW, STANDARD, AWS_SHALLOW])
def test_openvino_converts_the_car_graph_and_agrees(
    network, sensor, algorithm, frames, tmp_path
) -> None:
    meta = metadata_for(network, sensor, algorithm)
    model = randomised_model(meta, seed=len(network) + len(sensor) + len(algorithm))
    path = tmp_path / "model.pb"
    path.write_bytes(export_car_graph(model, meta))
    images = frames_for(sensor, frames)
    expected = torch_outputs(model, images)
    actual = run_openvino(str(path), input_name(meta.training_algorithm, sensor), images)
    assert actual.shape == expected.shape == (100, 10 if algorithm == "ppo_discrete" else 2)
    assert_agree(actual, expected, algorithm == "ppo_discrete")


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("network", [COMPACT, LEAN, SHALLOW])
def test_tensorflow_runs_the_car_graph_and_agrees(network, sensor, algorithm, frames) -> None:
    meta = metadata_for(network, sensor, algorithm)
    model = randomised_model(meta, seed=7)
    graph = export_car_graph(model, meta)
    images = frames_for(sensor, frames)
    actual = run_tensorflow(
        graph, input_name(meta.training_algorithm, sensor), output_name(meta.training_algorithm),
        images,
    )  # fmt: skip
    assert_agree(actual, torch_outputs(model, images), algorithm == "ppo_discrete")


def test_graph_names_and_layout(ppo_discrete) -> None:
    graph = parse_graph(export_car_graph(ppo_discrete.model, ppo_discrete.metadata))
    placeholder = [n for n in graph.node if n.op == "Placeholder"]
    assert [n.name for n in placeholder] == [
        "main_level/agent/main/online/network_0/FRONT_FACING_CAMERA/FRONT_FACING_CAMERA"
    ]
    dims = [d.size for d in placeholder[0].attr["shape"].shape.dim]
    assert dims == [-1, 120, 160, 1]  # NHWC
    assert graph.node[-1].name == "main_level/agent/main/online/network_1/ppo_head_0/policy"
    assert graph.node[-1].op == "Softmax"
    consumers = {i.split(":")[0] for n in graph.node for i in n.input}
    assert [n.name for n in graph.node if n.name not in consumers] == [graph.node[-1].name]
    allowed = {"Placeholder", "Const", "RealDiv", "AvgPool", "Conv2D", "BiasAdd", "Relu"}
    allowed |= {"Tanh", "Reshape", "MatMul", "Softmax"}
    assert {n.op for n in graph.node} <= allowed
    assert "AvgPool" in {n.op for n in graph.node}  # the lean network pools in the graph


def test_sac_output_name(sac_continuous) -> None:
    graph = parse_graph(export_car_graph(sac_continuous.model, sac_continuous.metadata))
    assert graph.node[-1].name == (
        "main_level/agent/policy/online/network_0/sac_policy_head_0/policy"
    )
    assert graph.node[0].name.startswith("main_level/agent/policy/online/network_0/")


def members(archive: bytes) -> dict[str, bytes]:
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def test_car_archive_has_one_pb_and_the_metadata_at_the_root(ppo_discrete) -> None:
    archive = build_car_archive(ppo_discrete.metadata, ppo_discrete.model)
    files = members(archive)
    assert sorted(files) == ["agent/model.pb", "model_metadata.json"]
    assert [n for n in files if n.endswith(".pb")] == ["agent/model.pb"]
    meta = json.loads(files["model_metadata.json"])
    assert meta["neural_network"] == SHALLOW  # a name every DeepRacer tool accepts
    assert meta[RACECRAFT_NETWORK_KEY] == LEAN
    assert meta["sensor"] == ["FRONT_FACING_CAMERA"]
    assert meta["action_space"] == ppo_discrete.metadata.to_json()["action_space"]
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        infos = tar.getmembers()
    assert all(i.mtime == ARCHIVE_MTIME and i.mode == 0o644 and i.uid == 0 for i in infos)
    from_zip = build_car_archive(ppo_discrete.metadata, checkpoint_bytes(ppo_discrete.model))
    assert from_zip == archive  # deterministic, and the same from the stored checkpoint


def test_deepracer_network_keeps_its_name(ppo_discrete) -> None:
    meta = metadata_for(SHALLOW, "FRONT_FACING_CAMERA", "ppo_discrete")
    files = members(build_car_archive(meta, randomised_model(meta, seed=1)))
    data = json.loads(files["model_metadata.json"])
    assert data["neural_network"] == SHALLOW and RACECRAFT_NETWORK_KEY not in data
