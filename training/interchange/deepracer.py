"""Importing DeepRacer's own models: the car's archive and the console's / DeepRacer-for-Cloud's
model folder, into a Racecraft checkpoint (an SB3 zip, as :mod:`training.rl.checkpoints` makes).

- **Car model** (:func:`import_car_archive`): a tar.gz with exactly one ``*.pb`` anywhere
  (DeepRacer writes ``agent/model.pb``) and ``model_metadata.json`` at the root.
- **Model folder** (:func:`import_deepracer_model`): the AWS console's virtual model or a
  DeepRacer-for-Cloud ``model/`` prefix, as tar.gz/tar/zip: ``model_metadata.json`` (at
  ``model/`` or the top), ``reward_function.py``, ``hyperparameters.json`` (``ip/`` or the
  top), optional ``training_params.yaml`` and metrics, and the frozen graphs DeepRacer writes
  beside its TensorFlow checkpoints, ``model/model_<iteration>.pb``, or without them the
  checkpoints themselves (``model/<iteration>_Step-<steps>.ckpt.index`` + ``.data-*``, read by
  :mod:`training.interchange.tfcheckpoint`). The best checkpoint
  (``deepracer_checkpoints.json``), else the last (``.coach_checkpoint``), else the highest
  iteration is imported, from its graph when there is one.

Archives are read in memory by :func:`training.interchange.archive.read_archive` (links,
absolute or ``..`` names, devices, oversized or bomb archives are refused). The weights come
only from the graph's Const nodes or the checkpoint's tensors
(:mod:`training.interchange.graphimport`, :mod:`training.interchange.checkpointimport`):
nothing is unpickled or executed. A camera + LIDAR model is read from its graph when the LIDAR
branch is laid out as Racecraft's car export writes it; other LIDAR layouts are refused. Only
the policy is taken (a frozen graph holds nothing else, and DeepRacer's PPO value network has
its own convolutions, which Racecraft's shared network cannot hold), so the value function (PPO)
or the critics (SAC) start fresh: :attr:`ImportedDeepRacerModel.value_head_fresh` says so.
Every failure is an :class:`~training.interchange.archive.ArchiveError` naming the file.
Graphs and checkpoints are measured before anything in them is built
(:mod:`training.interchange.graphbudget`). :func:`import_model_upload` takes either kind of
upload, or Racecraft's own; the worker runs it in a bounded child process
(:mod:`training.interchange.bounded`). :func:`model_folder_plan` names the files of a
DeepRacer-for-Cloud bucket prefix to fetch for an import (and none of its logs).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import BinaryIO

from training.interchange.archive import (
    EXTRA_SUFFIXES,
    ArchiveError,
    ImportedModel,
    ImportLimits,
    read_archive,
    read_json,
    read_metadata,
    reward_source,
    virtual_model,
)
from training.interchange.checkpointimport import policy_from_checkpoint
from training.interchange.graphimport import GraphImportError, policy_from_graph
from training.interchange.tfcheckpoint import CheckpointFormatError, read_checkpoint
from training.rl.checkpoints import checkpoint_bytes
from training.rl.hyperparams import HyperparameterError, Hyperparameters, parse_hyperparameters
from training.rl.metadata import ModelMetadata

_GRAPH_RE = re.compile(r"^model/model_(\d+)\.pb$")
_INDEX_RE = re.compile(r"^model/(\d+)_Step-\d+\.ckpt\.index$")
_CKPT_RE = re.compile(r"^(\d+)_Step-\d+\.ckpt")


@dataclass(frozen=True)
class ImportedDeepRacerModel:
    """A DeepRacer model made into a Racecraft one.

    ``checkpoint_bytes`` is an SB3 zip to store as ``model/<checkpoint_name>.zip``;
    ``metadata.neural_network`` names the Racecraft network that reproduces the graph.
    ``value_head_fresh`` is True when only the policy came from the upload (a clone then
    trains the value function or critics from scratch). ``hyperparameters`` and
    ``reward_function`` are None for a car archive, which has neither.
    """

    metadata: ModelMetadata
    checkpoint_bytes: bytes
    checkpoint_name: str
    source: str
    value_head_fresh: bool
    hyperparameters: Hyperparameters | None = None
    reward_function: str | None = None
    extra_files: dict[str, bytes] = field(default_factory=dict)


def _metadata(files: Mapping[str, bytes], *names: str) -> tuple[str, ModelMetadata]:
    name = next((n for n in names if n in files), None)
    if name is None:
        raise ArchiveError(f"model_metadata.json is missing (looked for {', '.join(names)})")
    return name, read_metadata(files, name)


def _convert(name: str, graph: bytes, metadata: ModelMetadata) -> tuple[ModelMetadata, bytes]:
    try:
        model, metadata = policy_from_graph(graph, metadata)
    except GraphImportError as exc:
        raise ArchiveError(f"{name}: {exc}") from None
    return metadata, checkpoint_bytes(model)


def import_car_archive(
    upload: bytes | BinaryIO, limits: ImportLimits | None = None
) -> ImportedDeepRacerModel:
    """A physical-car model (``agent/model.pb`` + ``model_metadata.json``) as a Racecraft model.

    Raises :class:`ArchiveError` for an unsafe archive, zero or several ``.pb`` files, a
    missing or bad ``model_metadata.json``, or a graph that fits no Racecraft network.
    """
    return _car_model(read_archive(upload, limits))


def _car_model(files: Mapping[str, bytes]) -> ImportedDeepRacerModel:
    graphs = sorted(n for n in files if n.endswith(".pb"))
    if len(graphs) != 1:
        found = ", ".join(graphs) if graphs else "none"
        raise ArchiveError(f"a car model holds exactly one .pb file (found {found})")
    _, metadata = _metadata(files, "model_metadata.json")
    metadata, zipped = _convert(graphs[0], files[graphs[0]], metadata)
    return ImportedDeepRacerModel(
        metadata=metadata,
        checkpoint_bytes=zipped,
        checkpoint_name="best",
        source=graphs[0],
        value_head_fresh=True,
    )


def _iteration(files: Mapping[str, bytes], name: str, role: str) -> int | None:
    """The iteration of the checkpoint a DeepRacer index file names (``13_Step-25173.ckpt``)."""
    if name not in files:
        return None
    if name.endswith(".json"):
        entry = read_json(files, name)
        entry = entry.get(role) if isinstance(entry, dict) else None
        text = entry.get("name") if isinstance(entry, dict) else None
    else:
        text = files[name].decode("utf-8", "replace").strip().splitlines()[0:1]
        text = text[0] if text else None
    match = _CKPT_RE.match(text) if isinstance(text, str) else None
    return int(match.group(1)) if match else None


def _choose_source(files: Mapping[str, bytes]) -> str:
    """The frozen graph (``model/model_<n>.pb``) or else the checkpoint index
    (``model/<n>_Step-<steps>.ckpt.index``) of the best, else last, else newest iteration."""
    graphs = {int(m.group(1)): n for n in files if (m := _GRAPH_RE.match(n))}
    checkpoints = {int(m.group(1)): n for n in files if (m := _INDEX_RE.match(n))}
    if not graphs and not checkpoints:
        raise ArchiveError(
            "no DeepRacer model to import: neither model/model_<iteration>.pb nor "
            "model/<iteration>_Step-<steps>.ckpt.index (with its .ckpt.data-* files, which "
            "model/.coach_checkpoint names)"
        )
    for index, role in (
        ("model/deepracer_checkpoints.json", "best_checkpoint"),
        ("model/deepracer_checkpoints.json", "last_checkpoint"),
        ("model/.coach_checkpoint", ""),
    ):
        iteration = _iteration(files, index, role)
        if iteration in graphs or iteration in checkpoints:
            return graphs.get(iteration) or checkpoints[iteration]
    return graphs[max(graphs)] if graphs else checkpoints[max(checkpoints)]


def _from_checkpoint(
    index_name: str, files: Mapping[str, bytes], metadata: ModelMetadata
) -> tuple[ModelMetadata, bytes]:
    prefix = index_name.removesuffix(".index")
    pattern = re.compile(rf"{re.escape(prefix)}\.data-(\d+)-of-\d+")
    found = {int(m.group(1)): n for n in files if (m := pattern.fullmatch(n))}
    shards = {shard: files[name] for shard, name in found.items()}
    try:
        tensors = read_checkpoint(files[index_name], shards, found)
        model, metadata = policy_from_checkpoint(tensors, metadata)
    except (CheckpointFormatError, GraphImportError) as exc:
        raise ArchiveError(f"{index_name}: {exc}") from None
    return metadata, checkpoint_bytes(model)


def import_deepracer_model(
    upload: bytes | BinaryIO, limits: ImportLimits | None = None
) -> ImportedDeepRacerModel:
    """A DeepRacer console virtual model or DeepRacer-for-Cloud model folder as a Racecraft
    model (see the module docstring for the files). Raises :class:`ArchiveError`."""
    return _model_folder(read_archive(upload, limits))


def _model_folder(files: Mapping[str, bytes]) -> ImportedDeepRacerModel:
    meta_name, metadata = _metadata(files, "model/model_metadata.json", "model_metadata.json")
    hp_name = next(
        (n for n in ("ip/hyperparameters.json", "hyperparameters.json") if n in files), None
    )
    if hp_name is None:
        raise ArchiveError("hyperparameters.json is missing (looked for ip/, the top folder)")
    try:
        hyperparameters = parse_hyperparameters(
            read_json(files, hp_name), metadata.training_algorithm
        )
    except HyperparameterError as exc:
        raise ArchiveError(f"{hp_name}: {exc}") from None
    if "reward_function.py" not in files:
        raise ArchiveError("reward_function.py is missing")
    reward = reward_source(files, "reward_function.py")
    source = _choose_source(files)
    if source.endswith(".pb"):
        metadata, zipped = _convert(source, files[source], metadata)
    else:
        metadata, zipped = _from_checkpoint(source, files, metadata)
    used = {meta_name, hp_name, "reward_function.py"}
    extra = {
        name: data
        for name, data in sorted(files.items())
        if name not in used and name.endswith(EXTRA_SUFFIXES) and not name.startswith("model/")
    }
    return ImportedDeepRacerModel(
        metadata=metadata,
        checkpoint_bytes=zipped,
        checkpoint_name="best",
        source=source,
        value_head_fresh=True,
        hyperparameters=hyperparameters,
        reward_function=reward,
        extra_files=extra,
    )


def import_deepracer_upload(
    upload: bytes | BinaryIO, limits: ImportLimits | None = None
) -> ImportedDeepRacerModel:
    """Either kind of DeepRacer upload, told apart by its files: a model folder has
    ``reward_function.py`` (or another file only a model folder has, :func:`_is_model_folder`);
    anything else is read as a car model. Raises :class:`ArchiveError`.
    """
    files = read_archive(upload, limits)
    return _model_folder(files) if _is_model_folder(files) else _car_model(files)


_FOLDER_FILES = ("reward_function.py", "hyperparameters.json", "training_params.yaml")


def _is_model_folder(files: Mapping[str, bytes]) -> bool:
    """A model folder, not the car's archive: it has a reward function, hyperparameters,
    training parameters or ``model/.coach_checkpoint`` (one with any of these but not the
    reward function is refused for that, not imported as a car model)."""
    return "model/.coach_checkpoint" in files or any(
        name.rsplit("/", 1)[-1] in _FOLDER_FILES for name in files
    )


DEEPRACER_SUFFIXES = (".pb", ".ckpt.index", ".index")


def import_model_upload(
    upload: bytes | BinaryIO, limits: ImportLimits | None = None
) -> ImportedModel | ImportedDeepRacerModel:
    """Any model upload: Racecraft's virtual model, else (when it holds a frozen graph or
    TensorFlow checkpoints) a DeepRacer one. The archive is read once. Raises
    :class:`ArchiveError`: Racecraft's reason for an upload with no DeepRacer files."""
    files = read_archive(upload, limits)
    try:
        return virtual_model(files)
    except ArchiveError as exc:
        if not any(_is_deepracer_file(name) for name in files):
            raise exc from None
    return _model_folder(files) if _is_model_folder(files) else _car_model(files)


def _is_deepracer_file(name: str) -> bool:
    """A frozen graph or a TensorFlow checkpoint's file, ``.coach_checkpoint`` included (a
    DeepRacer-on-AWS model folder whose checkpoint files are missing is still read as one,
    so the error names them)."""
    return (
        name.endswith(DEEPRACER_SUFFIXES)
        or ".ckpt." in name
        or name.rsplit("/", 1)[-1] == ".coach_checkpoint"
    )


_TRAINING_PARAMS_RE = re.compile(r"^training_params(?:_(\d+))?\.yaml$")


def model_folder_plan(
    sizes: Mapping[str, int], read: Callable[[Iterable[str]], Mapping[str, bytes]]
) -> dict[str, str]:
    """Which files of a DeepRacer-for-Cloud model prefix an import reads: name in the archive
    → path in the folder, from the folder's listing (``sizes``: path relative to the prefix →
    bytes; only its top, ``model/`` and ``ip/`` need be listed) and the content of the
    checkpoint indexes (``read(paths)``, which fetches them). Only the checkpoint
    :func:`import_deepracer_model` would import is named (its frozen graph, else its
    TensorFlow checkpoint files), never logs or metrics. The first worker's training
    parameters (``training_params.yaml``, else the lowest ``training_params_<n>.yaml``) are
    named ``training_params.yaml``. Raises :class:`ArchiveError` saying what is missing."""
    if not sizes:
        raise ArchiveError("there is nothing there")
    if "model/model_metadata.json" not in sizes:
        raise ArchiveError("no model/model_metadata.json")
    indexes = [n for n in ("model/deepracer_checkpoints.json", "model/.coach_checkpoint")
               if n in sizes]  # fmt: skip
    source = _choose_source({**dict.fromkeys(sizes, b""), **read(indexes)})
    weights = [source]
    if not source.endswith(".pb"):
        stem = source.removesuffix(".index")
        weights += sorted(n for n in sizes if n.startswith(f"{stem}.data-"))
    plan = {n: n for n in ("model/model_metadata.json", *indexes, *weights)}
    for name in ("ip/hyperparameters.json", "hyperparameters.json", "reward_function.py"):
        if name in sizes:
            plan[name] = name
    params = sorted((int(m.group(1) or 0), n) for n in sizes if (m := _TRAINING_PARAMS_RE.match(n)))
    if params:
        plan["training_params.yaml"] = params[0][1]
    return plan
