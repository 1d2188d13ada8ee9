"""Importing DeepRacer's models: graphs built the way DeepRacer builds them, the real
AWS-trained sample models, the round trip back to the car, and bad uploads."""

from __future__ import annotations

import json
import tarfile

import numpy as np
import pytest
import torch

from tests.support import tar_gz
from tests.training.interchange.carmodel_support import (
    metadata_for,
    randomised_model,
    run_tensorflow,
    stereo,
    torch_outputs,
)
from tests.training.interchange.deepracer_support import (
    aws_samples,
    checkpoint_of,
    deepracer_style_graph,
)
from training.interchange.archive import ArchiveError, ImportLimits
from training.interchange.carmodel import (
    build_car_archive,
    export_car_graph,
    input_name,
    output_name,
)
from training.interchange.deepracer import (
    import_car_archive,
    import_deepracer_model,
    import_deepracer_upload,
)
from training.interchange.export import load_checkpoint
from training.rl.policies import AWS_SHALLOW, COMPACT, LEAN, SHALLOW

REWARD = b"def reward_function(params):\n    return 1.0\n"
HYPERPARAMETERS = json.dumps({"batch_size": 64, "lr": 0.0003, "num_epochs": 10}).encode()


@pytest.fixture(scope="module")
def frames(camera_frames) -> np.ndarray:
    """100 float 0..255 camera frames (20 simulator frames at 5 brightnesses)."""
    base = camera_frames.astype(np.float32)
    return np.concatenate([np.clip(base * g, 0, 255) for g in (0.6, 0.8, 1.0, 1.2, 1.4)])


def imported_outputs(imported, images: np.ndarray) -> np.ndarray:
    model = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    return torch_outputs(model, images)


def reference(graph: bytes, meta, images: np.ndarray) -> np.ndarray:
    algorithm = meta.training_algorithm
    out = run_tensorflow(graph, input_name(algorithm, meta.camera), output_name(algorithm), images)
    return np.clip(out, -1, 1) if meta.action_space_type == "continuous" else out


@pytest.mark.slow
@pytest.mark.parametrize(
    "sensor, kind",
    [
        ("FRONT_FACING_CAMERA", "ppo_discrete"),
        ("STEREO_CAMERAS", "ppo_discrete"),
        ("FRONT_FACING_CAMERA", "ppo_continuous"),
        ("FRONT_FACING_CAMERA", "sac"),
    ],
)
def test_deepracer_style_graph_imports_exactly(sensor, kind, frames) -> None:
    meta = metadata_for(SHALLOW, sensor, kind)
    n_actions = len(meta.actions.actions) if kind == "ppo_discrete" else 2
    graph = deepracer_style_graph(sensor, kind, n_actions, seed=11)
    upload = tar_gz({"agent/model.pb": graph, "model_metadata.json": meta.dumps()})
    imported = import_car_archive(upload)
    assert imported.metadata.neural_network == AWS_SHALLOW
    assert imported.value_head_fresh
    images = stereo(frames) if sensor == "STEREO_CAMERAS" else frames
    expected = reference(graph, meta, images)
    actual = imported_outputs(imported, images)
    np.testing.assert_allclose(actual, expected, atol=1e-4, rtol=0)
    if kind == "ppo_discrete":
        assert (actual.argmax(1) == expected.argmax(1)).all()
    # exported again for the car, it computes the same thing
    model = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    again = reference(export_car_graph(model, imported.metadata), meta, images)
    np.testing.assert_allclose(again, expected, atol=1e-4, rtol=0)


@pytest.mark.slow
def test_real_aws_models_give_deepracers_outputs(frames) -> None:
    samples = aws_samples()
    assert sorted(samples.graphs) == [15, 30, 48]
    images = np.concatenate([samples.frames, frames])  # DeepRacer's own 3 frames, then ours
    for iteration, graph in samples.graphs.items():
        upload = tar_gz({"agent/model.pb": graph, "model_metadata.json": samples.metadata})
        imported = import_car_archive(upload)
        meta = imported.metadata
        assert (meta.neural_network, meta.camera, len(meta.actions.actions)) == (
            AWS_SHALLOW, "FRONT_FACING_CAMERA", 12,
        ), iteration  # fmt: skip
        expected = reference(graph, meta, images)
        actual = imported_outputs(imported, images)
        np.testing.assert_allclose(actual, expected, atol=1e-4, rtol=0, err_msg=str(iteration))
        assert (actual.argmax(1) == expected.argmax(1)).all()


@pytest.mark.slow
def test_model_folder_picks_the_best_checkpoints_graph() -> None:
    samples = aws_samples()
    folder = {
        "model/model_metadata.json": samples.metadata,
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "training_params.yaml": b"WORLD_NAME: reInvent2019_track\n",
        "model/.coach_checkpoint": b"48_Step-98123.ckpt\n",
        "model/deepracer_checkpoints.json": json.dumps(
            {"best_checkpoint": {"name": "30_Step-61000.ckpt"}}
        ).encode(),
        **{f"model/model_{i}.pb": g for i, g in samples.graphs.items()},
    }
    imported = import_deepracer_model(tar_gz(folder))
    assert imported.source == "model/model_30.pb"
    assert imported.reward_function == REWARD.decode()
    assert imported.hyperparameters.batch_size == 64
    assert "training_params.yaml" in imported.extra_files
    del folder["model/deepracer_checkpoints.json"]
    assert import_deepracer_model(tar_gz(folder)).source == "model/model_48.pb"
    assert import_deepracer_upload(tar_gz(folder)).source == "model/model_48.pb"
    car = {"agent/model.pb": samples.graphs[15], "model_metadata.json": samples.metadata}
    assert import_deepracer_upload(tar_gz(car)).reward_function is None


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["ppo_discrete", "sac"])
def test_tensorflow_checkpoint_without_a_graph_imports_exactly(kind, frames) -> None:
    meta = metadata_for(SHALLOW, "FRONT_FACING_CAMERA", kind)
    n_actions = len(meta.actions.actions) if kind == "ppo_discrete" else 2
    graph = deepracer_style_graph("FRONT_FACING_CAMERA", kind, n_actions, seed=21)
    folder = {
        "model/model_metadata.json": meta.dumps(),
        "hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "model/.coach_checkpoint": b"12_Step-3400.ckpt\n",
        **checkpoint_of(graph),
    }
    assert "model/12_Step-3400.ckpt.data-00000-of-00001" in folder
    imported = import_deepracer_model(tar_gz(folder))
    assert imported.source == "model/12_Step-3400.ckpt.index"
    expected = reference(graph, meta, frames)
    np.testing.assert_allclose(imported_outputs(imported, frames), expected, atol=1e-4, rtol=0)


@pytest.fixture(scope="module")
def car_files() -> dict[str, bytes]:
    meta = metadata_for(SHALLOW, "FRONT_FACING_CAMERA", "ppo_discrete")
    graph = deepracer_style_graph("FRONT_FACING_CAMERA", "ppo_discrete", 10, seed=3)
    return {"agent/model.pb": graph, "model_metadata.json": meta.dumps()}


def test_bad_car_archives_say_what_is_wrong(car_files) -> None:
    cases = {
        "exactly one .pb file (found none)": {"model_metadata.json": b"{}"},
        "exactly one .pb file (found a.pb, agent/model.pb)": {**car_files, "a.pb": b"x"},
        "model_metadata.json is missing": {"agent/model.pb": car_files["agent/model.pb"]},
        "not a TensorFlow GraphDef": {**car_files, "agent/model.pb": b"\xff" * 40},
    }
    for message, files in cases.items():
        with pytest.raises(ArchiveError, match=message.replace("(", r"\(").replace(")", r"\)")):
            import_car_archive(tar_gz(files))


def test_names_and_shapes_that_do_not_fit(car_files) -> None:
    stereo_meta = metadata_for(SHALLOW, "STEREO_CAMERAS", "ppo_discrete")
    with pytest.raises(ArchiveError, match="no input node .*STEREO_CAMERAS/STEREO_CAMERAS"):
        import_car_archive(tar_gz({**car_files, "model_metadata.json": stereo_meta.dumps()}))
    five = metadata_for(SHALLOW, "FRONT_FACING_CAMERA", "ppo_discrete").to_json()
    five["action_space"] = five["action_space"][:5]
    with pytest.raises(ArchiveError, match=r"policy head: the graph has shape \(10, 512\)"):
        import_car_archive(tar_gz({**car_files, "model_metadata.json": json.dumps(five).encode()}))
    odd = deepracer_style_graph("FRONT_FACING_CAMERA", "ppo_discrete", 10, 3, [(8, 5, 3)])
    with pytest.raises(ArchiveError, match=r"unsupported network: .*\[\(8, 5, 3\)\]"):
        import_car_archive(tar_gz({**car_files, "agent/model.pb": odd}))
    sac = metadata_for(SHALLOW, "FRONT_FACING_CAMERA", "sac")
    with pytest.raises(ArchiveError, match="no input node main_level/agent/policy"):
        import_car_archive(tar_gz({**car_files, "model_metadata.json": sac.dumps()}))


def test_unsafe_archives_are_refused(car_files) -> None:
    def link(tar: tarfile.TarFile) -> None:
        info = tarfile.TarInfo("agent/other.pb")
        info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tar.addfile(info)

    with pytest.raises(ArchiveError, match="links are not allowed"):
        import_car_archive(tar_gz(car_files, link))
    with pytest.raises(ArchiveError, match="'..' is not allowed"):
        import_car_archive(tar_gz({**car_files, "../evil.py": b"x"}))
    bomb = tar_gz({**car_files, "zeros.bin": bytes(40_000_000)})
    with pytest.raises(ArchiveError, match="once uncompressed"):
        import_car_archive(bomb, ImportLimits(max_uncompressed_bytes=30_000_000))


def test_model_folder_needs_a_graph(car_files) -> None:
    base = {
        "model/model_metadata.json": car_files["model_metadata.json"],
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
    }
    with pytest.raises(ArchiveError, match="not a TensorFlow checkpoint index"):
        import_deepracer_model(tar_gz({**base, "model/5_Step-100.ckpt.index": b"x" * 60}))
    with pytest.raises(ArchiveError, match="no DeepRacer model to import"):
        import_deepracer_model(tar_gz(base))
    with pytest.raises(ArchiveError, match="reward_function.py is missing"):
        import_deepracer_model(tar_gz({k: v for k, v in base.items() if "reward" not in k}))


def test_imported_model_clones_for_training(car_files) -> None:
    """Training a clone builds the network by name and loads the imported checkpoint into it."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from racing.env import RacingEnv
    from training.rl.algorithms import load_model
    from training.rl.hyperparams import parse_hyperparameters

    imported = import_car_archive(tar_gz(car_files))
    meta = imported.metadata
    env = DummyVecEnv(
        [lambda: RacingEnv("racecraft_summit", action_space=meta.actions.to_metadata())]
    )
    try:
        clone = load_model(
            "clipped_ppo", imported.checkpoint_bytes, env, parse_hyperparameters({}),
            network=meta.neural_network,
        )  # fmt: skip
        frame = np.full((1, 1, 120, 160), 90.0, np.float32)
        source = load_checkpoint(imported.checkpoint_bytes, meta)
        for model in (clone, source):
            model.policy.set_training_mode(False)
        with torch.no_grad():
            a = clone.policy.get_distribution(torch.from_numpy(frame / 255)).distribution.probs
            b = source.policy.get_distribution(torch.from_numpy(frame / 255)).distribution.probs
        torch.testing.assert_close(a, b)
    finally:
        env.close()


@pytest.mark.parametrize("network", [COMPACT, LEAN])
def test_racecrafts_own_car_download_imports_back_as_its_network(network, frames) -> None:
    """The car archive of a Racecraft network (the racing preset's compact one, the lean one)
    imports back as that network, its policy giving the car graph's outputs."""
    meta = metadata_for(network, "FRONT_FACING_CAMERA", "ppo_discrete")
    model = randomised_model(meta, seed=3)
    imported = import_car_archive(build_car_archive(meta, model))
    assert imported.metadata.neural_network == network
    expected = torch_outputs(model, frames)
    actual = imported_outputs(imported, frames)
    np.testing.assert_allclose(actual, expected, atol=1e-4, rtol=0)
    assert (actual.argmax(1) == expected.argmax(1)).all()
