"""Exporting trained models: the "ONNX policy" download, the virtual-model and logs archives;
and loading a checkpoint safely (weights only) for a given ``model_metadata.json``. The car's
download (a frozen TensorFlow graph) is :mod:`training.interchange.carmodel`.

**ONNX policy** (:func:`export_onnx`): input ``"observation"``, float32 ``(1, C, 120, 160)``,
the grayscale camera in 0..255 (``C`` = 1, or 2 for the stereo pair); the /255 scaling is inside
the graph; with a LIDAR a second input named by its sensor id (``"LIDAR"``, ``"SECTOR_LIDAR"``
or ``"DISCRETIZED_SECTOR_LIDAR"``), float32 ``(1, n)``, as the simulator gives it. Output for a
discrete space ``"action_probabilities"`` ``(1, n)`` (softmax over the
actions of ``model_metadata.json``, in order); for a continuous one ``"action"`` ``(1, 2)`` =
``[steering_deg, speed_m_s]``, deterministic: PPO's mean clipped to the ranges, SAC's
tanh-squashed mean rescaled to them (what ``model.predict(obs, deterministic=True)`` returns).
Exported with torch's TorchScript-based exporter (``dynamo=False``), opset 17: the torch.export
("dynamo") exporter needs the onnxscript package, which is not a dependency, and the legacy
exporter handles these small static graphs reliably, offline.

**Archives** are deterministic tar.gz files (:mod:`training.interchange.tarball`); the logs
archive's layout is :mod:`training.interchange.logarchive`'s.

**Checkpoints** are SB3 ``model.save()`` zips. :func:`load_checkpoint` never unpickles the
file's ``data`` (SB3 stores classes with cloudpickle there, which would run code from an
uploaded file): it builds a fresh model from the metadata and loads the tensors with
``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import io
import json
import warnings
from collections.abc import Mapping

import gymnasium as gym
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from torch import nn

from training.interchange.carmodel import (  # noqa: F401 - build_car_archive re-exported
    build_car_archive,
    car_metadata,
)
from training.interchange.coachexport import (
    CoachExportError,
    download_refusal,
    droa_checkpoint_files,
)
from training.interchange.logarchive import build_logs_archive  # noqa: F401 - re-exported
from training.interchange.tarball import (  # noqa: F401 - re-exported for callers
    ARCHIVE_MTIME,
    ExportError,
    deterministic_tar_gz,
)
from training.rl.checkpoints import (  # noqa: F401 - re-exported for callers
    CheckpointError,
    checkpoint_bytes,
    load_checkpoint,
    new_model,
    read_checkpoint_tensors,
)
from training.rl.metadata import MetadataError, ModelMetadata, parse_metadata
from training.rl.policies import CameraLidarExtractor, split_sensors

OPSET = 17
INPUT_NAME = "observation"
DISCRETE_OUTPUT = "action_probabilities"
CONTINUOUS_OUTPUT = "action"
MAX_CHECKPOINT_BYTES = 1_000_000_000  # uncompressed tensors in one checkpoint zip
CHECKPOINTS_INDEX = "model/deepracer_checkpoints.json"
VIRTUAL_MODEL_REQUIRED = (
    "model/model_metadata.json",
    "ip/hyperparameters.json",
    "reward_function.py",
)
VIRTUAL_MODEL_EXCLUDED = ("training-simtrace/", "evaluation/", "videos/", "export/", "output/")
"""Folders left out of the virtual model (DeepRacer leaves out sim-traces, videos, output)."""
DROA_COPIES = {
    "model_metadata.json": "model/model_metadata.json",
    "training_params.yaml": "ip/training_params.yaml",
}
"""Files DeepRacer-on-AWS's import reads at the top of the folder (its
source/libs/lambda/src/import-workflow/utils/ImportHelper.ts: ``model_metadata.json``,
``reward_function.py``, ``training_params.yaml``, ``ip/hyperparameters.json``), as copies of
ours: the top name → the file it copies. Its own export lays the model out so (the model's
folder with ``sagemaker-artifacts/`` taken out: source/libs/lambda/src/async/assetpackaging.ts).
"""


# --- ONNX ------------------------------------------------------------------------------------


class _Features(nn.Module):
    """A features extractor fed as the exported graph's inputs: the image in 0..255 and, for
    a camera + LIDAR extractor, the LIDAR vector."""

    def __init__(self, extractor: nn.Module) -> None:
        super().__init__()
        self.extractor = extractor
        self.keys = (
            (extractor.camera_key, extractor.lidar_key)
            if isinstance(extractor, CameraLidarExtractor)
            else None
        )

    def forward(self, observation: torch.Tensor, lidar: torch.Tensor | None = None) -> torch.Tensor:
        if self.keys is None:
            return self.extractor(observation / 255.0)
        camera_key, lidar_key = self.keys
        return self.extractor({camera_key: observation / 255.0, lidar_key: lidar})


class DiscretePolicy(nn.Module):
    """PPO, discrete: image 0..255 (and LIDAR) → softmax over the actions."""

    def __init__(self, policy: nn.Module) -> None:
        super().__init__()
        self.extractor = _Features(policy.pi_features_extractor)
        self.mlp = policy.mlp_extractor
        self.head = policy.action_net

    def forward(self, observation: torch.Tensor, lidar: torch.Tensor | None = None) -> torch.Tensor:
        latent = self.mlp.forward_actor(self.extractor(observation, lidar))
        return torch.softmax(self.head(latent), dim=-1)


class BoxPolicy(nn.Module):
    """PPO or SAC, continuous: image 0..255 → deterministic ``[steering_deg, speed]``."""

    def __init__(self, model: BaseAlgorithm) -> None:
        super().__init__()
        policy = model.policy
        self.squashed = isinstance(model, SAC)
        if self.squashed:
            actor = policy.actor
            self.extractor, self.latent, self.head = (
                _Features(actor.features_extractor),
                actor.latent_pi,
                actor.mu,
            )
        else:
            self.extractor = _Features(policy.pi_features_extractor)
            self.head = policy.action_net
            self.latent = policy.mlp_extractor.policy_net
        space = model.action_space
        self.register_buffer("low", torch.as_tensor(space.low, dtype=torch.float32))
        self.register_buffer("high", torch.as_tensor(space.high, dtype=torch.float32))

    def forward(self, observation: torch.Tensor, lidar: torch.Tensor | None = None) -> torch.Tensor:
        mean = self.head(self.latent(self.extractor(observation, lidar)))
        if self.squashed:
            return self.low + 0.5 * (torch.tanh(mean) + 1.0) * (self.high - self.low)
        return torch.minimum(torch.maximum(mean, self.low), self.high)


def export_onnx(model: BaseAlgorithm | bytes, metadata: ModelMetadata | None = None) -> bytes:
    """The policy of ``model`` (an SB3 PPO/SAC model, or its saved zip) as ONNX bytes.

    Zip bytes need ``metadata`` and are loaded safely (:func:`load_checkpoint`: SB3's own
    loader is never used, it unpickles). The metadata, when given, is also stored in the ONNX
    file's ``model_metadata`` property. Raises :class:`ExportError` (or
    :class:`CheckpointError` for bad bytes).
    """
    if isinstance(model, bytes | bytearray | memoryview):
        if metadata is None:
            raise ExportError("exporting a saved checkpoint needs its model_metadata.json")
        model = load_checkpoint(bytes(model), metadata)
    space = model.action_space
    if isinstance(space, gym.spaces.Discrete):
        if isinstance(model, SAC):
            raise ExportError("SAC needs a continuous action space")
        wrapper: nn.Module = DiscretePolicy(model.policy)
        output = DISCRETE_OUTPUT
    elif isinstance(space, gym.spaces.Box) and space.shape == (2,):
        wrapper, output = BoxPolicy(model), CONTINUOUS_OUTPUT
    else:
        raise ExportError(f"cannot export a policy with action space {space}")
    space = model.policy.observation_space
    lidar_key, inputs = None, [INPUT_NAME]
    if isinstance(space, gym.spaces.Dict):
        camera_key, lidar_key = split_sensors(space)
        inputs.append(lidar_key)
        space = space.spaces[camera_key]
    shape = tuple(space.shape)
    if len(shape) != 3 or shape[1:] != (120, 160) or shape[0] not in (1, 2):
        raise ExportError(f"the policy takes images of shape {shape}, not (C, 120, 160)")
    wrapper.eval()
    sample: tuple = (torch.full((1, *shape), 128.0),)
    if lidar_key is not None:
        size = model.policy.observation_space.spaces[lidar_key].shape[0]
        sample = (*sample, torch.full((1, size), 0.5))
    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the TorchScript exporter announces its deprecation
        torch.onnx.export(
            wrapper,
            sample,
            buffer,
            dynamo=False,
            input_names=inputs,
            output_names=[output],
            opset_version=OPSET,
            do_constant_folding=True,
        )
    return _with_properties(buffer.getvalue(), metadata)


def _with_properties(onnx_bytes: bytes, metadata: ModelMetadata | None) -> bytes:
    import onnx

    proto = onnx.load_from_string(onnx_bytes)
    onnx.checker.check_model(proto)
    proto.producer_name = "racecraft"
    props = {"input_scale": "0..255 grayscale"}
    if metadata is not None:
        props["model_metadata"] = json.dumps(metadata.to_json(), sort_keys=True)
    onnx.helper.set_model_props(proto, props)
    return proto.SerializeToString()


# --- archives --------------------------------------------------------------------------------


def checkpoints_index(best: str, last: str, racecraft: tuple[str, str] | None = None) -> bytes:
    """DeepRacer's ``deepracer_checkpoints.json`` naming the best and last checkpoints, and,
    where those are DeepRacer's, the Racecraft checkpoints (zips) they were written from."""
    data: dict[str, dict[str, str]] = {
        "best_checkpoint": {"name": best}, "last_checkpoint": {"name": last}
    }  # fmt: skip
    if racecraft is not None:
        data["best_checkpoint"]["racecraft_checkpoint"] = racecraft[0]
        data["last_checkpoint"]["racecraft_checkpoint"] = racecraft[1]
    return (json.dumps(data, indent=2, sort_keys=True) + "\n").encode()


def build_virtual_model_archive(files: Mapping[str, bytes]) -> bytes:
    """``virtualmodel-<name>.tar.gz``: a model folder that :mod:`training.interchange.archive`
    imports back, laid out as DeepRacer-on-AWS exports a virtual model (names relative to the
    folder, no top folder; ``model_metadata.json`` and ``training_params.yaml`` also at the top,
    :data:`DROA_COPIES`).

    ``files`` maps names inside the model folder (``model/model_metadata.json``,
    ``ip/hyperparameters.json``, ``ip/training_params.yaml``, ``reward_function.py``,
    ``model/<checkpoint>.zip``, optional ``model/deepracer_checkpoints.json``,
    ``metrics/*.json``...) to bytes. Sim-traces, evaluations, videos and exports are left out.
    ``model_metadata.json`` names the network as DeepRacer's tools want it, Racecraft's own kept
    aside (:func:`~training.interchange.carmodel.car_metadata`), as the car's download does.

    The best checkpoint (``best``, else the only one or the last by name) is also written as
    DeepRacer's TensorFlow checkpoint when DeepRacer's trainer can hold the model and the
    download stays importable here (:func:`~training.interchange.coachexport.download_refusal`),
    so DeepRacer-on-AWS's validation accepts the folder; ``deepracer_checkpoints.json`` then
    names it as best and last, and each entry's ``racecraft_checkpoint`` names the zip Racecraft
    imports back. Otherwise the index names the zips: ``best``/``last`` when those exist, else
    the only checkpoint for both. Raises :class:`ExportError` when a required file or the
    checkpoint is missing.
    """
    kept = {n: bytes(d) for n, d in files.items() if not n.startswith(VIRTUAL_MODEL_EXCLUDED)}
    missing = [name for name in VIRTUAL_MODEL_REQUIRED if name not in kept]
    checkpoints = sorted(
        n[len("model/") : -len(".zip")]
        for n in kept
        if n.startswith("model/") and n.endswith(".zip")
    )
    if not checkpoints:
        missing.append("model/<checkpoint>.zip")
    if missing:
        raise ExportError(f"a virtual model needs {', '.join(missing)}")
    if len(checkpoints) == 1:
        best = last = checkpoints[0]
    else:
        best = "best" if "best" in checkpoints else checkpoints[-1]
        last = "last" if "last" in checkpoints else checkpoints[-1]
    metadata = _metadata(kept)
    if metadata is not None:  # DeepRacer's network name, Racecraft's kept aside
        kept["model/model_metadata.json"] = car_metadata(metadata)
    deepracer = _deepracer_checkpoint(kept, metadata, best)
    if deepracer is not None:
        name, tf_files = deepracer
        kept |= tf_files
        kept[CHECKPOINTS_INDEX] = checkpoints_index(name, name, racecraft=(best, last))
    elif CHECKPOINTS_INDEX not in kept:
        kept[CHECKPOINTS_INDEX] = checkpoints_index(best, last)
    for top, source in DROA_COPIES.items():
        if source in kept:
            kept[top] = kept[source]
    return deterministic_tar_gz(kept)


def _metadata(files: Mapping[str, bytes]) -> ModelMetadata | None:
    try:
        return parse_metadata(files["model/model_metadata.json"])
    except MetadataError:
        return None


def _deepracer_checkpoint(
    files: Mapping[str, bytes], metadata: ModelMetadata | None, best: str
) -> tuple[str, dict[str, bytes]] | None:
    """DeepRacer's TensorFlow checkpoint of the ``best`` zip, or None when DeepRacer's trainer
    cannot hold the model or the download would grow too big (:func:`download_refusal`), or
    the zip does not load."""
    if metadata is None or download_refusal(metadata) is not None:
        return None
    zipped = files[f"model/{best}.zip"]
    try:
        return droa_checkpoint_files(zipped, metadata, load_checkpoint(zipped, metadata))
    except (CheckpointError, CoachExportError):
        return None
