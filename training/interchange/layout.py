"""Where a model's objects live in the store: DeepRacer-for-Cloud's folder layout."""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import UTC, datetime

from training.storage import StoreError

_MODEL_ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_FOLDER_RE = re.compile(r"^[A-Za-z0-9_-]{1,96}$")
_STAMP_RE = re.compile(r"^[0-9]{14}$")


def model_prefix(folder: str | int) -> str:
    """The folder of one model: ``"<folder>/"``, 1-96 of ``A-Z a-z 0-9 _ -`` (its id for older
    models, ``u<owner>-<name>`` for new ones)."""
    text = str(folder)
    if isinstance(folder, bool) or not _FOLDER_RE.match(text):
        raise StoreError(f"model folder {folder!r} must be 1-96 letters, digits, '_' or '-'")
    return f"{text}/"


def evaluation_stamp(when: datetime) -> str:
    """DeepRacer-for-Cloud's name of an evaluation: ``YYYYMMDDhhmmss`` in UTC."""
    return when.astimezone(UTC).strftime("%Y%m%d%H%M%S")


def _stamp(value: str) -> str:
    if not isinstance(value, str) or not _STAMP_RE.match(value):
        raise StoreError(f"evaluation stamp {value!r} must be 14 digits (YYYYMMDDhhmmss)")
    return value


def _name(value: str | int, what: str) -> str:
    text = str(value)
    if isinstance(value, bool) or not _MODEL_ID_RE.match(text):
        raise StoreError(f"{what} {value!r} must be 1-64 letters, digits, '_' or '-'")
    return text


@dataclass(frozen=True)
class ModelKeys:
    """Object keys of one model, in DeepRacer-for-Cloud's layout (architecture.md)::

    <id>/model/model_metadata.json   <id>/model/<checkpoint>.zip   <id>/model/best, last
    <id>/ip/hyperparameters.json     <id>/reward_function.py
    <id>/training-simtrace/<n>-iteration.csv   <id>/metrics/TrainingMetrics.json
    <id>/metrics/EvaluationMetrics-<stamp>.json
    <id>/evaluation-<stamp>/evaluation-simtrace/0-iteration.csv
    <id>/videos/<eval>.mp4           <id>/export/car.tar.gz

    ``<stamp>`` is the evaluation's start, ``YYYYMMDDhhmmss`` UTC (:func:`evaluation_stamp`).
    Evaluations stored before that live under ``<id>/evaluation/<eval id>/`` and
    ``EvaluationMetrics-<eval id>.json`` (:meth:`legacy_evaluation_simtrace`).
    """

    model_id: str | int

    @property
    def prefix(self) -> str:
        return model_prefix(self.model_id)

    @property
    def metadata(self) -> str:
        return f"{self.prefix}model/model_metadata.json"

    @property
    def hyperparameters(self) -> str:
        return f"{self.prefix}ip/hyperparameters.json"

    @property
    def reward_function(self) -> str:
        return f"{self.prefix}reward_function.py"

    @property
    def checkpoints_index(self) -> str:
        """DeepRacer's ``deepracer_checkpoints.json`` (names of the best and last checkpoint)."""
        return f"{self.prefix}model/deepracer_checkpoints.json"

    def checkpoint(self, name: str) -> str:
        """A checkpoint file ``model/<name>.zip`` (``name`` without the ``.zip``)."""
        return f"{self.prefix}model/{_name(name, 'checkpoint name')}.zip"

    @property
    def best(self) -> str:
        return self.checkpoint("best")

    @property
    def last(self) -> str:
        return self.checkpoint("last")

    def simtrace(self, iteration: int) -> str:
        return f"{self.prefix}training-simtrace/{_iteration(iteration)}-iteration.csv"

    @property
    def training_metrics(self) -> str:
        return f"{self.prefix}metrics/TrainingMetrics.json"

    def evaluation_metrics(self, stamp: str) -> str:
        return f"{self.prefix}metrics/EvaluationMetrics-{_stamp(stamp)}.json"

    def evaluation_simtrace(self, stamp: str) -> str:
        return f"{self.prefix}evaluation-{_stamp(stamp)}/evaluation-simtrace/0-iteration.csv"

    def legacy_evaluation_simtrace(self, eval_id: str | int) -> str:
        """Where evaluations were stored before DeepRacer-for-Cloud's names (read only)."""
        folder = f"{self.prefix}evaluation/{_name(eval_id, 'evaluation id')}"
        return f"{folder}/evaluation-simtrace/0-iteration.csv"

    def video(self, eval_id: str | int) -> str:
        return f"{self.prefix}videos/{_name(eval_id, 'evaluation id')}.mp4"

    @property
    def car_export(self) -> str:
        return f"{self.prefix}export/car.tar.gz"


def _iteration(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise StoreError(f"iteration must be a whole number >= 0, not {n!r}")
    return n


@dataclass(frozen=True)
class RaceKeys:
    """Object keys of one head-to-head race: ``races/<id>/broadcast.mp4``, and each car's
    sim-trace in DeepRacer-for-Cloud's evaluation layout under the race's folder of that car
    (``races/<id>/<model id>/evaluation-<stamp>/evaluation-simtrace/0-iteration.csv``, beside
    its ``model/model_metadata.json``), so deepracer-utils reads a car's folder as a model's.
    League entries keep a frozen copy of their checkpoint at :meth:`frozen_checkpoint`."""

    race_id: int

    @property
    def prefix(self) -> str:
        return f"races/{_name(self.race_id, 'race id')}/"

    @property
    def video(self) -> str:
        return f"{self.prefix}broadcast.mp4"

    def car_folder(self, model_id: int) -> str:
        return f"{self.prefix}{_name(model_id, 'model id')}/"

    def car_simtrace(self, model_id: int, stamp: str) -> str:
        folder = self.car_folder(model_id)
        return f"{folder}evaluation-{_stamp(stamp)}/evaluation-simtrace/0-iteration.csv"

    def car_metadata(self, model_id: int) -> str:
        return f"{self.car_folder(model_id)}model/model_metadata.json"

    @staticmethod
    def frozen_checkpoint(scope: str, entry: int) -> str:
        """A league entry's frozen weights: ``league/<scope>/<entry>.zip``."""
        return f"league/{_name(scope, 'league scope')}/{_name(entry, 'entry id')}.zip"
