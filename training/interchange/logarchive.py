"""The logs download, laid out as DeepRacer-on-AWS lays out its logs archives.

The store keeps a model's logs in DeepRacer-for-Cloud's layout (:mod:`.layout`), which
``deepracer-utils`` reads from the bucket (``S3FileHandler``) or a copied folder
(``FSFileHandler``). Its reader of a downloaded archive, ``TarFileHandler``, knows only the
console's layout: one wrapper folder, then ``sim-trace/training/<run>/training-simtrace/`` and
``sim-trace/evaluation/<run>/evaluation-simtrace/`` (DeepRacer-for-Cloud's names at the
archive's root fail its path patterns). So the archive is::

    <folder>/sim-trace/training/<training run>/training-simtrace/<k>-iteration.csv
    <folder>/sim-trace/evaluation/<stamp>/evaluation-simtrace/0-iteration.csv
    <folder>/metrics/...   <folder>/model/model_metadata.json   <folder>/ip/hyperparameters.json
    <folder>/reward_function.py

``<folder>`` is the model's folder name, ``<stamp>`` the evaluation's (``YYYYMMDDhhmmss``,
or an older evaluation's id). Read as it is, ``DeepRacerLog(filehandler=TarFileHandler(path))``;
extracted, ``DeepRacerLog("<folder>")`` (``FSFileHandler`` finds the same console layout and
also reads the model's metadata and hyperparameters). There are no SimApp console logs
(``logs/training/*-simulation.log``): Racecraft has no RoboMaker, so ``load_robomaker_logs``
has nothing to read; the sim-traces carry the same rows.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from training.interchange.tarball import ExportError, deterministic_tar_gz

TRAINING_SIMTRACE = re.compile(r"^training-simtrace/(?P<file>[^/]+-iteration\.csv)$")
EVALUATION_SIMTRACE = re.compile(
    r"^evaluation(?:-(?P<stamp>[0-9]{14})|/(?P<id>[^/]+))/evaluation-simtrace/(?P<file>[^/]+)$"
)
"""DeepRacer-for-Cloud's ``evaluation-<stamp>/...`` and older evaluations' ``evaluation/<id>/``."""


def logs_archive_names(files: Mapping[str, bytes], *, training_run: str) -> dict[str, bytes]:
    """The model's log files (names inside its store folder) under the console's names
    (without the wrapper folder); files outside the sim-trace folders keep their names."""
    out: dict[str, bytes] = {}
    for name, data in files.items():
        if match := TRAINING_SIMTRACE.match(name):
            name = f"sim-trace/training/{training_run}/training-simtrace/{match['file']}"
        elif match := EVALUATION_SIMTRACE.match(name):
            run = match["stamp"] or match["id"]
            name = f"sim-trace/evaluation/{run}/evaluation-simtrace/{match['file']}"
        out[name] = data
    return out


def build_logs_archive(files: Mapping[str, bytes], *, folder: str, training_run: str) -> bytes:
    """The logs download: ``files`` (names inside the model's store folder) as a deterministic
    tar.gz in the console's layout under ``<folder>/`` (see the module). Raises ExportError
    when there is nothing to archive or a name is unsafe."""
    if not files:
        raise ExportError("there are no logs to download yet")
    for part in (folder, training_run):
        if not part or "/" in part or part in (".", ".."):
            raise ExportError(f"bad folder name in the logs archive: {part!r}")
    named = logs_archive_names(files, training_run=training_run)
    return deterministic_tar_gz({f"{folder}/{name}": data for name, data in named.items()})
