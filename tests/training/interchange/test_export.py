"""ONNX export of real tiny models (checked with onnxruntime against torch) and the archives."""

from __future__ import annotations

import gzip
import io
import json
import tarfile

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from training.interchange.export import (
    CheckpointError,
    ExportError,
    build_logs_archive,
    build_virtual_model_archive,
    checkpoint_bytes,
    deterministic_tar_gz,
    export_onnx,
    load_checkpoint,
)
from training.rl.metadata import build_metadata


def session(onnx_bytes: bytes) -> ort.InferenceSession:
    return ort.InferenceSession(onnx_bytes, providers=["CPUExecutionProvider"])


def channel_first(frame: np.ndarray) -> np.ndarray:
    """(120, 160, C) uint8 → the ONNX input (1, C, 120, 160) float32 0..255."""
    return frame.transpose(2, 0, 1)[None].astype(np.float32)


def test_discrete_ppo_matches_torch(ppo_discrete, camera_frames) -> None:
    model = ppo_discrete.model
    sess = session(export_onnx(model, ppo_discrete.metadata))
    (inp,), (out,) = sess.get_inputs(), sess.get_outputs()
    assert (inp.name, inp.shape, inp.type) == ("observation", [1, 1, 120, 160], "tensor(float)")
    assert (out.name, out.shape) == ("action_probabilities", [1, 10])
    for frame in camera_frames:
        (probs,) = sess.run(None, {"observation": channel_first(frame)})
        obs_tensor, _ = model.policy.obs_to_tensor(frame)
        with torch.no_grad():
            expected = model.policy.get_distribution(obs_tensor).distribution.probs.numpy()
        np.testing.assert_allclose(probs, expected, rtol=1e-4, atol=1e-5)
        assert probs.sum() == pytest.approx(1.0, abs=1e-5)
        action, _ = model.predict(frame, deterministic=True)
        assert int(np.argmax(probs)) == int(action)


@pytest.mark.parametrize("fixture", ["ppo_continuous", "sac_continuous"])
def test_continuous_matches_predict(fixture, request, camera_frames) -> None:
    tiny = request.getfixturevalue(fixture)
    sess = session(export_onnx(tiny.model))
    (out,) = sess.get_outputs()
    assert (out.name, out.shape) == ("action", [1, 2])
    low, high = tiny.model.action_space.low, tiny.model.action_space.high
    for frame in camera_frames:
        (action,) = sess.run(None, {"observation": channel_first(frame)})
        expected, _ = tiny.model.predict(frame, deterministic=True)
        np.testing.assert_allclose(action[0], expected, rtol=1e-4, atol=1e-4)
        assert np.all(action[0] >= low - 1e-5) and np.all(action[0] <= high + 1e-5)


def test_ppo_continuous_clips_to_the_box(ppo_continuous) -> None:
    """A mean far outside the range is clipped, as ``predict`` clips it."""
    model = ppo_continuous.model
    saved = model.policy.action_net.bias.detach().clone()
    try:
        with torch.no_grad():
            model.policy.action_net.bias[:] = torch.tensor([500.0, -500.0])
        (action,) = session(export_onnx(model)).run(
            None, {"observation": np.zeros((1, 1, 120, 160), np.float32)}
        )
    finally:
        with torch.no_grad():
            model.policy.action_net.bias[:] = saved
    np.testing.assert_allclose(action[0], [20.0, 0.5])


def test_export_from_checkpoint_bytes(sac_continuous, ppo_discrete, camera_frames) -> None:
    frame = channel_first(camera_frames[3])
    for tiny in (sac_continuous, ppo_discrete):
        direct = session(export_onnx(tiny.model)).run(None, {"observation": frame})[0]
        zipped = checkpoint_bytes(tiny.model)
        safe = session(export_onnx(zipped, tiny.metadata)).run(None, {"observation": frame})[0]
        np.testing.assert_allclose(safe, direct, rtol=1e-5, atol=1e-6)
        with pytest.raises(ExportError, match="needs its model_metadata.json"):
            export_onnx(zipped)


def test_onnx_carries_the_metadata(ppo_discrete) -> None:
    proto = onnx.load_from_string(export_onnx(ppo_discrete.model, ppo_discrete.metadata))
    assert proto.opset_import[0].version >= 17
    props = {p.key: p.value for p in proto.metadata_props}
    assert json.loads(props["model_metadata"]) == ppo_discrete.metadata.to_json()


def test_stereo_export() -> None:
    meta = build_metadata(
        action_space=[
            {"steering_angle": 0, "speed": 1},
            {"steering_angle": 20, "speed": 1},
            {"steering_angle": -20, "speed": 1},
        ],
        sensor=["STEREO_CAMERAS"],
        neural_network="RACECRAFT_LEAN_CNN",
    )
    from training.interchange.export import new_model

    sess = session(export_onnx(new_model(meta)))
    assert sess.get_inputs()[0].shape == [1, 2, 120, 160]
    (probs,) = sess.run(None, {"observation": np.full((1, 2, 120, 160), 90, np.float32)})
    assert probs.shape == (1, 3)


def test_load_checkpoint_roundtrip_keeps_weights(ppo_discrete) -> None:
    loaded = load_checkpoint(checkpoint_bytes(ppo_discrete.model), ppo_discrete.metadata)
    for key, value in ppo_discrete.model.policy.state_dict().items():
        assert torch.equal(loaded.policy.state_dict()[key], value)


def test_load_checkpoint_mismatches(ppo_discrete, sac_continuous) -> None:
    ppo_zip = checkpoint_bytes(ppo_discrete.model)
    with pytest.raises(CheckpointError, match="PPO model but model_metadata.json says"):
        load_checkpoint(ppo_zip, sac_continuous.metadata)
    fewer = build_metadata(
        action_space=[{"steering_angle": 0, "speed": 1}] * 4, neural_network="RACECRAFT_LEAN_CNN"
    )
    with pytest.raises(CheckpointError, match="10 discrete actions but .* lists 4"):
        load_checkpoint(ppo_zip, fewer)
    other_net = build_metadata(action_space=ppo_discrete.metadata.actions)
    with pytest.raises(CheckpointError, match="do not fit neural_network DEEP_CONV"):
        load_checkpoint(ppo_zip, other_net)
    with pytest.raises(CheckpointError, match="not a readable zip"):
        load_checkpoint(b"not a zip", ppo_discrete.metadata)


# --- archives --------------------------------------------------------------------------------


def members(archive: bytes) -> dict[str, tarfile.TarInfo]:
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        return {m.name: m for m in tar.getmembers()}


def read_member(archive: bytes, name: str) -> bytes:
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        return tar.extractfile(name).read()


def virtual_files(tiny) -> dict[str, bytes]:
    return {
        "model/model_metadata.json": tiny.metadata.dumps(),
        "ip/hyperparameters.json": b'{"batch_size": 64}',
        "reward_function.py": b"def reward_function(params):\n    return 1.0\n",
        "model/best.zip": checkpoint_bytes(tiny.model),
        "metrics/TrainingMetrics.json": b'{"metrics": []}',
        "training-simtrace/0-iteration.csv": b"episode,steps\n",
        "videos/e1.mp4": b"\x00\x00",
    }


def test_virtual_model_archive(ppo_discrete) -> None:
    files = virtual_files(ppo_discrete)
    archive = build_virtual_model_archive(files)
    assert sorted(members(archive)) == [
        "ip/hyperparameters.json",
        "metrics/TrainingMetrics.json",
        "model/best.zip",
        "model/deepracer_checkpoints.json",
        "model/model_metadata.json",
        "model_metadata.json",  # where DeepRacer-on-AWS's import reads it (test_droa_export.py)
        "reward_function.py",
    ]
    index = json.loads(read_member(archive, "model/deepracer_checkpoints.json"))
    assert index == {"best_checkpoint": {"name": "best"}, "last_checkpoint": {"name": "best"}}
    assert build_virtual_model_archive(dict(reversed(files.items()))) == archive
    both = {**files, "model/last.zip": files["model/best.zip"]}
    index = json.loads(
        read_member(build_virtual_model_archive(both), "model/deepracer_checkpoints.json")
    )
    assert index == {"best_checkpoint": {"name": "best"}, "last_checkpoint": {"name": "last"}}


@pytest.mark.parametrize(
    "missing", ["model/model_metadata.json", "reward_function.py", "model/best.zip"]
)
def test_virtual_model_archive_needs_files(ppo_discrete, missing) -> None:
    files = virtual_files(ppo_discrete)
    del files[missing]
    with pytest.raises(ExportError, match="a virtual model needs"):
        build_virtual_model_archive(files)


def test_logs_archive_and_names() -> None:
    logs = {"training-simtrace/1-iteration.csv": b"a\n", "metrics/TrainingMetrics.json": b"{}"}
    archive = build_logs_archive(logs, folder="u1-m", training_run="training-20260101000000")
    assert sorted(members(archive)) == [  # the console's layout, which TarFileHandler reads
        "u1-m/metrics/TrainingMetrics.json",
        "u1-m/sim-trace/training/training-20260101000000/training-simtrace/1-iteration.csv",
    ]
    assert archive[:2] == b"\x1f\x8b"
    assert gzip.decompress(archive)  # the gzip header carries no name and no time
    assert archive[4:8] == b"\x00\x00\x00\x00"
    with pytest.raises(ExportError):
        build_logs_archive({}, folder="u1-m", training_run="t")
    for bad in ("/etc/passwd", "../x", "a/../../b", "a\\b"):
        with pytest.raises(ExportError, match="bad archive member name"):
            deterministic_tar_gz({bad: b"x"})


def test_long_names_are_fine() -> None:
    name = "evaluation/" + "e" * 60 + "/evaluation-simtrace/" + "1" * 60 + "-iteration.csv"
    assert list(members(deterministic_tar_gz({name: b"x"}))) == [name]
