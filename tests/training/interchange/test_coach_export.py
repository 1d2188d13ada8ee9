"""The virtual model's DeepRacer checkpoint, for DeepRacer-on-AWS's import (issue 27): exactly
the variables DeepRacer's model validation restores, by name and shape (recorded from the
SimApp's own Coach graph: ``data/simapp_ppo_variables.json``); the same policy when read back
through the DeepRacer import; and a clear reason for the models DeepRacer cannot hold."""

from __future__ import annotations

import io
import json
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.support import tar_gz
from training.interchange.archive import ArchiveError, import_virtual_model
from training.interchange.checkpointimport import policy_from_checkpoint
from training.interchange.coachexport import (
    CoachExportError,
    checkpoint_name,
    coach_export_refusal,
    coach_variables,
    download_refusal,
)
from training.interchange.deepracer import import_deepracer_model, import_model_upload
from training.interchange.export import build_virtual_model_archive, checkpoint_bytes
from training.interchange.policybuild import GraphImportError
from training.interchange.tfcheckpoint import read_checkpoint, read_index, write_checkpoint
from training.rl.checkpoints import load_checkpoint, new_model
from training.rl.metadata import build_metadata, parse_metadata
from training.rl.policies import AWS_SHALLOW, AWS_STANDARD, LEAN, SHALLOW, STANDARD

SIMAPP = json.loads((Path(__file__).parent / "data" / "simapp_ppo_variables.json").read_text())
RACECRAFT_NETWORK = {SHALLOW: AWS_SHALLOW, STANDARD: AWS_STANDARD}
REWARD = b"def reward_function(params):\n    return 1.0\n"


def racecraft_metadata(case: str):
    """The case's DeepRacer metadata, with Racecraft's network of DeepRacer's layout."""
    deepracer = SIMAPP["metadata"][case]
    data = {**deepracer, "neural_network": RACECRAFT_NETWORK[deepracer["neural_network"]]}
    return parse_metadata(json.dumps(data).encode())


def perturbed(metadata, seed: int = 0):
    """A fresh model with every weight moved off its initial value, so every layer counts."""
    model = new_model(metadata)
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in model.policy.parameters():
            parameter.add_(torch.randn(parameter.shape, generator=generator) * 0.02)
    return model


def folder(metadata, model) -> dict[str, bytes]:
    return {
        "model/model_metadata.json": metadata.dumps(),
        "ip/hyperparameters.json": b'{"batch_size": 64}',
        "ip/training_params.yaml": b'WORLD_NAME: "reInvent2019_track"\n',
        "reward_function.py": REWARD,
        "model/best.zip": checkpoint_bytes(model),
    }


def zip_members(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


def members(archive: bytes) -> dict[str, bytes]:
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


@pytest.mark.parametrize("case", sorted(SIMAPP["variables"]))
def test_the_checkpoint_holds_what_deepracers_validation_restores(case) -> None:
    metadata = racecraft_metadata(case)
    variables = coach_variables(new_model(metadata), metadata)
    expected = SIMAPP["variables"][case]
    assert sorted(variables) == sorted(expected)
    for name, shape in expected.items():
        assert list(np.shape(variables[name])) == shape, name
        assert variables[name].dtype == np.float32, name


def test_the_download_carries_the_checkpoint_deepracer_on_aws_validates() -> None:
    metadata = racecraft_metadata("ppo_discrete_5_actions_camera_shallow")
    model = perturbed(metadata)
    files = folder(metadata, model)
    files["model/last.zip"] = files["model/best.zip"]
    archive = members(build_virtual_model_archive(files))
    described = json.loads(archive["model/model_metadata.json"])  # what the SimApp builds from
    assert described["neural_network"] == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    assert described["racecraft_neural_network"] == AWS_SHALLOW
    name = "0_Step-0.ckpt"  # a fresh model: no update, no step
    assert archive["model/.coach_checkpoint"] == name.encode()  # no newline, as the SimApp
    index = json.loads(archive["model/deepracer_checkpoints.json"])
    assert index["best_checkpoint"] == {"name": name, "racecraft_checkpoint": "best"}
    assert index["last_checkpoint"] == {"name": name, "racecraft_checkpoint": "last"}
    entries = read_index(archive[f"model/{name}.index"])
    assert set(entries) == set(SIMAPP["variables"]["ppo_discrete_5_actions_camera_shallow"])
    tensors = read_checkpoint(
        archive[f"model/{name}.index"], {0: archive[f"model/{name}.data-00000-of-00001"]}
    )
    scope = "main_level/agent/main/online/network_1/FRONT_FACING_CAMERA/Conv2d_0"
    kernel = model.policy.pi_features_extractor.cnn[0].weight.detach().numpy()
    assert np.array_equal(tensors[f"{scope}/kernel"], kernel.transpose(2, 3, 1, 0))

    # Racecraft imports its own download back from the zip, unchanged.
    back = import_model_upload(build_virtual_model_archive(files))
    assert back.checkpoint_name == "best"
    # Compared by what the zips hold: a zip records when each member was written (to 2 s), so
    # two saves of one model straddling a 2-second boundary differ in their bytes.
    assert zip_members(back.checkpoint_bytes) == zip_members(
        checkpoint_bytes(load_checkpoint(files["model/best.zip"], metadata))
    )


def same_policy(model, back, channels: int) -> None:
    frames = torch.rand(3, channels, 120, 160, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        ours = model.policy.get_distribution(frames).distribution
        theirs = back.policy.get_distribution(frames).distribution
    if isinstance(ours, torch.distributions.Categorical):
        expected, got = ours.probs, theirs.probs
    else:  # the import maps DeepRacer's -1..1 mean back onto the ranges
        expected, got = ours.mean, theirs.mean
    assert torch.allclose(got, expected, atol=1e-5), (got - expected).abs().max()


@pytest.mark.parametrize(
    "case", [c for c in sorted(SIMAPP["variables"]) if not c.endswith("_standard")]
)
def test_the_deepracer_checkpoint_reads_back_as_the_same_policy(case) -> None:
    metadata = racecraft_metadata(case)
    model = perturbed(metadata, seed=5)
    index, data = write_checkpoint(coach_variables(model, metadata))
    back, _ = policy_from_checkpoint(read_checkpoint(index, {0: data}), metadata)
    same_policy(model, back, metadata.channels)


def test_what_deepracer_on_aws_uploads_imports_as_the_same_policy() -> None:
    """The folder without Racecraft's zips (DRoA's upload skips them), read by the DeepRacer
    import, acts as the model did."""
    metadata = racecraft_metadata("ppo_discrete_5_actions_camera_shallow")
    model = perturbed(metadata, seed=5)
    archive = members(build_virtual_model_archive(folder(metadata, model)))
    imported = import_deepracer_model(
        tar_gz({n: d for n, d in archive.items() if not n.endswith(".zip")})
    )
    assert imported.source == "model/0_Step-0.ckpt.index"
    same_policy(model, load_checkpoint(imported.checkpoint_bytes, imported.metadata), 1)


def test_models_deepracer_cannot_hold_are_said_and_keep_their_download() -> None:
    actions = [{"steering_angle": a, "speed": 1.0} for a in (-20, 0, 20)]
    lean = build_metadata(action_space=actions, neural_network=LEAN)
    sac = build_metadata(
        action_space={"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 1, "high": 4}},
        training_algorithm="sac", neural_network=AWS_SHALLOW,
    )  # fmt: skip
    lidar = build_metadata(
        action_space=actions, sensor=["FRONT_FACING_CAMERA", "LIDAR"], neural_network=AWS_SHALLOW
    )
    assert "DeepRacer 3-layer CNN, heads as in AWS" in coach_export_refusal(lean)
    assert "SAC" in coach_export_refusal(sac)
    assert "LIDAR" in coach_export_refusal(lidar)
    with pytest.raises(CoachExportError, match="not laid out as DeepRacer's"):
        coach_variables(new_model(lean), lean)
    standard = racecraft_metadata("ppo_discrete_5_actions_camera_standard")
    assert coach_export_refusal(standard) is None
    assert "past the 200 MB that Racecraft imports back" in download_refusal(standard)
    archive = members(build_virtual_model_archive(folder(lean, new_model(lean))))
    assert not any(".ckpt" in n or n.endswith(".coach_checkpoint") for n in archive)
    index = json.loads(archive["model/deepracer_checkpoints.json"])
    assert index["best_checkpoint"] == {"name": "best"}


def test_a_checkpoint_is_named_by_its_iteration_and_steps() -> None:
    metadata = racecraft_metadata("ppo_discrete_5_actions_camera_shallow")
    model = new_model(metadata)
    model._n_updates, model.n_epochs, model.num_timesteps = 120, 10, 9600
    assert checkpoint_name(checkpoint_bytes(model)) == "12_Step-9600.ckpt"
    assert checkpoint_name(b"not a zip") == "0_Step-0.ckpt"


def test_a_racecraft_network_that_is_not_one_is_refused_on_import() -> None:
    metadata = racecraft_metadata("ppo_discrete_5_actions_camera_shallow")
    files = members(build_virtual_model_archive(folder(metadata, new_model(metadata))))
    described = json.loads(files["model/model_metadata.json"])
    described["racecraft_neural_network"] = "RACECRAFT_TINY_TEST_CNN"
    files["model/model_metadata.json"] = json.dumps(described).encode()
    with pytest.raises(ArchiveError, match="racecraft_neural_network .* is not a Racecraft"):
        import_virtual_model(tar_gz(files))


def test_deepracers_5_layer_checkpoint_is_refused_not_imported_without_its_dense_layer() -> None:
    """DeepRacer's 5-layer CNN has a 64→64 dense layer on every pixel (``Dense_8``, seen in the
    SimApp's graph); Racecraft's 5-layer network does not, so its checkpoint cannot be imported
    (before, the layer was silently left out)."""
    metadata = racecraft_metadata("ppo_discrete_5_actions_camera_standard")
    variables = coach_variables(new_model(metadata), metadata)
    dense = "main_level/agent/main/online/network_1/FRONT_FACING_CAMERA/Dense_8/kernel"
    variables[dense] = np.random.default_rng(0).normal(size=(64, 64)).astype(np.float32)
    index, data = write_checkpoint(variables)
    with pytest.raises(GraphImportError, match="Dense_8/kernel is a dense layer on every pixel"):
        policy_from_checkpoint(read_checkpoint(index, {0: data}), metadata)
