"""DeepRacer-on-AWS (DRoA, aws-solutions/deepracer-on-aws) models import into Racecraft: its
``virtualmodel-<name>.tar.gz`` export and the model folder its import page takes, tarred.
Each archive is written here from DRoA's layout (no DRoA file is kept in the project):

- the export is the model's folder with ``sagemaker-artifacts/`` taken out, no top folder
  (source/libs/lambda/src/async/assetpackaging.ts): ``model_metadata.json`` and
  ``reward_function.py`` at the top (ImportHelper.ts keeps them there), the training job's
  ``training_params.yaml``, ``ip/hyperparameters.json``, ``model/`` and ``metrics/``;
- the folder a user imports (source/docs/import/README.md): ``model/.coach_checkpoint`` and the
  checkpoint files, ``model_metadata.json``, ``reward_function.py``, ``training_params.yaml``,
  ``hyperparameters.json`` at the folder's top, optional ``metrics/training/training-*.json``.

The weights come from the frozen graph DeepRacer writes beside each checkpoint
(``model/model_<iteration>.pb``), here Racecraft's car export of a tiny model. TensorFlow is
not installed to write real ``.ckpt`` files: stand-ins are there for the layout, and the
graph of the same iteration is what is read (real checkpoints are read in
test_deepracer_import.py)."""

from __future__ import annotations

import io
import json
import tarfile

import pytest
from django.contrib.auth import get_user_model

from tests.support import tar_gz
from training import services
from training.interchange.archive import ArchiveError
from training.interchange.deepracer import ImportedDeepRacerModel, import_model_upload
from training.interchange.export import build_car_archive
from training.rl.checkpoints import load_checkpoint
from training.rl.evaluation import EvaluationSettings, evaluate, sb3_policy
from training.rollout.envs import EnvSpec

REWARD = b"def reward_function(params):\n    return 1.0\n"
HYPERPARAMETERS = json.dumps(
    {"batch_size": 64, "beta_entropy": 0.01, "discount_factor": 0.999, "loss_type": "huber",
     "lr": 0.0003, "num_episodes_between_training": 20, "num_epochs": 10}
).encode()  # fmt: skip
CHECKPOINT = "7_Step-1400.ckpt"


def training_params(world: str) -> bytes:
    """A training job's ``training_params.yaml`` with keys DRoA writes
    (source/libs/lambda/src/workflow/types/simulationEnvironmentVariables.ts)."""
    return (
        f"WORLD_NAME: {world}\nJOB_TYPE: TRAINING\nRACE_TYPE: TIME_TRIAL\n"
        "TRACK_DIRECTION_CLOCKWISE: false\nCHANGE_START_POSITION: true\n"
        "MODEL_NAME: droa-model\nBODY_SHELL_TYPE: deepracer\nCAR_COLOR: Black\n"
        "NUMBER_OF_OBSTACLES: 0\nOBJECT_POSITIONS: []\n"
    ).encode()


def car_files(tiny) -> dict[str, bytes]:
    with tarfile.open(fileobj=io.BytesIO(build_car_archive(tiny.metadata, tiny.model))) as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def droa_export(tiny, world: str = "reInvent2019_track") -> dict[str, bytes]:
    """The members of DRoA's ``virtualmodel-<name>.tar.gz`` for a model whose best and last
    checkpoint is iteration 7."""
    car = car_files(tiny)
    index = {"best_checkpoint": {"name": CHECKPOINT, "avg_comp_pct": 100.0},
             "last_checkpoint": {"name": CHECKPOINT, "avg_comp_pct": 100.0}}  # fmt: skip
    return {
        "model_metadata.json": car["model_metadata.json"],
        "reward_function.py": REWARD,
        "training_params.yaml": training_params(world),
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "model/model_metadata.json": car["model_metadata.json"],
        "model/.coach_checkpoint": f"{CHECKPOINT}\n".encode(),
        "model/deepracer_checkpoints.json": json.dumps(index).encode(),
        f"model/{CHECKPOINT}.index": b"stand-in",
        f"model/{CHECKPOINT}.data-00000-of-00001": b"stand-in",
        f"model/{CHECKPOINT}.meta": b"stand-in",
        "model/model_7.pb": car["agent/model.pb"],
        "metrics/training/2025-06-01T10:00:00.000Z-droa-training.json": b'{"metrics": []}',
    }


def droa_folder(tiny) -> dict[str, bytes]:
    """The folder a user picks on DRoA's import page, tarred with its own name on top, with
    ``hyperparameters.json`` at its top as the import guide's table puts it."""
    files = droa_export(tiny)
    del files["model/model_metadata.json"]
    files["hyperparameters.json"] = files.pop("ip/hyperparameters.json")
    files["metrics/training/training-droa.json"] = files.pop(
        "metrics/training/2025-06-01T10:00:00.000Z-droa-training.json"
    )
    return {f"my-model/{name}": data for name, data in files.items()}


@pytest.mark.parametrize("layout", [droa_export, droa_folder])
def test_droa_models_import(layout, ppo_discrete) -> None:
    imported = import_model_upload(tar_gz(layout(ppo_discrete)))
    assert isinstance(imported, ImportedDeepRacerModel)
    assert imported.source == "model/model_7.pb"
    assert imported.reward_function == REWARD.decode()
    assert imported.hyperparameters.batch_size == 64
    assert imported.metadata.actions == ppo_discrete.metadata.actions
    assert "training_params.yaml" in imported.extra_files


@pytest.mark.slow
@pytest.mark.parametrize("fixture", ["ppo_discrete", "ppo_continuous"])
def test_an_imported_droa_model_drives_the_same_laps(fixture, request) -> None:
    tiny = request.getfixturevalue(fixture)
    imported = import_model_upload(tar_gz(droa_export(tiny)))
    again = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    spec = EnvSpec(track="racecraft_summit", action_space=tiny.metadata.actions.to_metadata())
    settings = EvaluationSettings(laps=3, record_video=False)
    original = evaluate(sb3_policy(tiny.model), spec, settings).to_json()
    droa = evaluate(sb3_policy(again), spec, settings).to_json()
    assert original["laps"] and droa["laps"] == original["laps"]


@pytest.mark.parametrize(
    ("missing", "message"),
    [
        (("model_metadata.json", "model/model_metadata.json"), "model_metadata.json is missing"),
        (("reward_function.py",), "reward_function.py is missing"),
        (("ip/hyperparameters.json",), "hyperparameters.json is missing"),
        (("model/model_7.pb", f"model/{CHECKPOINT}.index"), r"model/\.coach_checkpoint names"),
    ],
)
def test_a_broken_droa_model_says_what_is_missing(missing, message, ppo_discrete) -> None:
    files = droa_export(ppo_discrete)
    for name in missing:
        del files[name]
    with pytest.raises(ArchiveError, match=message):
        import_model_upload(tar_gz(files))


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("world", "track", "note"),
    [
        ("racecraft_oval", "racecraft_oval", ""),
        ("reInvent2019_track", "reInvent2019_track", ""),
        ("H_track", None, "H_track"),
    ],  # DeepRacer's tracks are built in; H_track is not
)
def test_a_droa_export_becomes_a_model(world, track, note, ppo_discrete, tmp_path,
                                       settings) -> None:  # fmt: skip
    settings.STORE_DIR = tmp_path / "store"
    owner = get_user_model().objects.create_user("ida", password="x-long-pass-1")
    upload = tar_gz(droa_export(ppo_discrete, world=world))
    model = services.model_import(owner=owner, name="from-droa", upload=upload)
    assert model.imported and model.has_checkpoint
    assert model.track_id == (track or model.track_id) and note in model.import_note
    assert "DeepRacer" in model.description
