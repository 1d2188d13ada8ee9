"""Exports of camera + LIDAR and stereo + LIDAR models, named as DeepRacer names them: the car
graph takes the camera at ``.../network_0/<CAMERA>/<CAMERA>`` and the LIDAR at
``.../network_0/<LIDAR>/<LIDAR>`` and gives what the torch policy gives (checked with OpenVINO,
as the car converts it, and with the graph reader); the ONNX policy takes both inputs; the
metadata lists both sensors, camera first, as the car's loader reads them."""

from __future__ import annotations

import io
import json
import tarfile

import numpy as np
import onnxruntime as ort
import pytest
import torch

from tests.training.interchange.carmodel_support import (
    CAR_PRECISION,
    CONTINUOUS,
    DISCRETE,
    randomised_model,
    run_openvino,
    stereo,
)
from training.interchange.carmodel import (
    build_car_archive,
    export_car_graph,
    input_name,
    output_name,
)
from training.interchange.export import BoxPolicy, DiscretePolicy, checkpoint_bytes, export_onnx
from training.interchange.tfgraph import parse_graph, run_graph
from training.rl.metadata import build_metadata
from training.rl.policies import LEAN, SHALLOW

CASES = [
    ("clipped_ppo", DISCRETE, "FRONT_FACING_CAMERA", "LIDAR", 64),
    ("sac", CONTINUOUS, "STEREO_CAMERAS", "SECTOR_LIDAR", 8),
    ("clipped_ppo", CONTINUOUS, "STEREO_CAMERAS", "DISCRETIZED_SECTOR_LIDAR", 64),
]
IDS = ["ppo-camera-lidar", "sac-stereo-sector", "ppo-stereo-discretized"]


def inputs(camera: str, size: int, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """``n`` NHWC 0..255 frames and LIDAR readings in the simulator's ranges."""
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (n, 120, 160, 1)).astype(np.float32)
    if camera == "STEREO_CAMERAS":
        frames = stereo(frames)
    lidar = rng.uniform(0.15, 1.0, (n, size)).astype(np.float32)
    return frames, lidar


def torch_outputs(model, frames: np.ndarray, lidar: np.ndarray) -> np.ndarray:
    """What the car graph must give: softmax probabilities, or the action in -1..1."""
    discrete = hasattr(model.action_space, "n")
    wrapper = DiscretePolicy(model.policy) if discrete else BoxPolicy(model)
    with torch.no_grad():
        out = wrapper(torch.as_tensor(frames.transpose(0, 3, 1, 2)), torch.as_tensor(lidar))
    out = out.numpy()
    if discrete:
        return out
    low, high = model.action_space.low, model.action_space.high
    return 2.0 * (out - low) / (high - low) - 1.0


@pytest.mark.parametrize("algorithm, actions, camera, lidar, size", CASES, ids=IDS)
@pytest.mark.parametrize("network", [LEAN, SHALLOW])
def test_car_graph_takes_camera_and_lidar_and_agrees(
    network, algorithm, actions, camera, lidar, size, tmp_path
) -> None:
    meta = build_metadata(action_space=actions, training_algorithm=algorithm,
                          sensor=[camera, lidar], neural_network=network)  # fmt: skip
    model = randomised_model(meta, seed=size + len(network))
    graph_bytes = export_car_graph(model, meta)
    graph = parse_graph(graph_bytes)
    placeholders = {n.name: [d.size for d in n.attr["shape"].shape.dim]
                    for n in graph.node if n.op == "Placeholder"}  # fmt: skip
    head = "policy" if algorithm == "sac" else "main"
    assert placeholders == {
        f"main_level/agent/{head}/online/network_0/{camera}/{camera}": [
            -1, 120, 160, 2 if camera == "STEREO_CAMERAS" else 1],
        f"main_level/agent/{head}/online/network_0/{lidar}/{lidar}": [-1, size],
    }  # fmt: skip
    assert graph.node[-1].name == output_name(algorithm)
    frames, readings = inputs(camera, size)
    expected = torch_outputs(model, frames, readings)
    feeds = {input_name(algorithm, camera): frames, input_name(algorithm, lidar): readings}
    np.testing.assert_allclose(
        run_graph(graph, feeds, output_name(algorithm)), expected, atol=1e-4, rtol=0
    )
    path = tmp_path / "model.pb"
    path.write_bytes(graph_bytes)
    ov = pytest.importorskip("openvino", reason="OpenVINO is in the dev extra")
    converted = ov.convert_model(
        str(path),
        input=[(f"{input_name(algorithm, camera)}:0", [1, *frames.shape[1:]]),
               (f"{input_name(algorithm, lidar)}:0", [1, size])],
    )  # fmt: skip
    compiled = ov.Core().compile_model(converted, "CPU", CAR_PRECISION)
    actual = np.concatenate(
        [compiled([frames[i : i + 1], readings[i : i + 1]])[compiled.output(0)]
         for i in range(len(frames))]
    )  # fmt: skip
    np.testing.assert_allclose(actual, expected, atol=1e-3, rtol=0)
    if algorithm == "clipped_ppo" and actions is DISCRETE:
        assert (actual.argmax(axis=1) == expected.argmax(axis=1)).all()


def test_camera_only_graph_is_unchanged_by_the_lidar_branch(tmp_path) -> None:
    """A camera-only export keeps one input and runs in OpenVINO as before."""
    meta = build_metadata(action_space=DISCRETE, sensor=["FRONT_FACING_CAMERA"],
                          neural_network=LEAN)  # fmt: skip
    model = randomised_model(meta, seed=2)
    path = tmp_path / "model.pb"
    path.write_bytes(export_car_graph(model, meta))
    graph = parse_graph(path.read_bytes())
    assert [n.op for n in graph.node].count("Placeholder") == 1
    assert "ConcatV2" not in {n.op for n in graph.node}
    frames, _ = inputs("FRONT_FACING_CAMERA", 64, n=4)
    actual = run_openvino(str(path), input_name("clipped_ppo", "FRONT_FACING_CAMERA"), frames)
    assert actual.shape == (4, len(DISCRETE))


def test_car_archive_lists_both_sensors() -> None:
    meta = build_metadata(action_space=DISCRETE, sensor=["STEREO_CAMERAS", "LIDAR"],
                          neural_network=LEAN)  # fmt: skip
    model = randomised_model(meta, seed=5)
    archive = build_car_archive(meta, checkpoint_bytes(model))
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        files = {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}
    assert sorted(files) == ["agent/model.pb", "model_metadata.json"]
    assert json.loads(files["model_metadata.json"])["sensor"] == ["STEREO_CAMERAS", "LIDAR"]
    names = {n.name for n in parse_graph(files["agent/model.pb"]).node if n.op == "Placeholder"}
    assert names == {input_name("clipped_ppo", "STEREO_CAMERAS"),
                     input_name("clipped_ppo", "LIDAR")}  # fmt: skip
    assert "lidar_config" not in json.loads(files["model_metadata.json"])


def test_discretized_lidar_tells_the_car_its_bins() -> None:
    """deepracer-spec §2.3: the car bins a discretized sector LIDAR by ``lidar_config``; the
    simulator's 8 sectors × 8 values up to 2 m are written for it."""
    meta = build_metadata(action_space=DISCRETE, neural_network=LEAN,
                          sensor=["FRONT_FACING_CAMERA", "DISCRETIZED_SECTOR_LIDAR"])  # fmt: skip
    archive = build_car_archive(meta, randomised_model(meta, seed=6))
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        data = json.loads(tar.extractfile("model_metadata.json").read())
    assert data["lidar_config"] == {"num_sectors": 8, "num_values_per_sector": 8,
                                    "clipping_dist": 2.0}  # fmt: skip


@pytest.mark.parametrize("algorithm, actions, camera, lidar, size", CASES, ids=IDS)
def test_onnx_policy_takes_the_lidar_by_its_sensor_name(
    algorithm, actions, camera, lidar, size
) -> None:
    meta = build_metadata(action_space=actions, training_algorithm=algorithm,
                          sensor=[camera, lidar], neural_network=LEAN)  # fmt: skip
    model = randomised_model(meta, seed=9)
    sess = ort.InferenceSession(export_onnx(model, meta), providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["observation", lidar]
    assert sess.get_inputs()[1].shape == [1, size]
    frames, readings = inputs(camera, size, n=3)
    for frame, reading in zip(frames, readings, strict=True):
        obs = {"observation": frame.transpose(2, 0, 1)[None], lidar: reading[None]}
        (out,) = sess.run(None, obs)
        if algorithm == "clipped_ppo" and actions is DISCRETE:
            expected = torch_outputs(model, frame[None], reading[None])
        else:  # the action in its units: what predict(deterministic=True) gives
            image = frame.astype(np.uint8)
            expected, _ = model.predict({camera: image, lidar: reading}, deterministic=True)
            expected = np.asarray(expected)[None]
        np.testing.assert_allclose(out, expected, atol=1e-4, rtol=0)
