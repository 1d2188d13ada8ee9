"""Our logs through the community's own reader, ``deepracer-utils`` (no mocks): cars driven by
the rollout workers' stepper (real env steps, rows stamped where they are recorded), logged as
the training job logs them, archived as the logs download lays them out; read from the
archive (``TarFileHandler``) and from the extracted folder (``FSFileHandler``), and its
stability and real-time-factor analysis run on the rows."""

from __future__ import annotations

import json
import math
import tarfile
from pathlib import Path

import numpy as np
import pytest

from racing.env import RacingEnv
from racing.rules import RaceRules
from racing.simtrace import TraceRow, to_csv
from training.interchange.logarchive import build_logs_archive, logs_archive_names
from training.interchange.logbook import LoggedIteration, TrainingLog
from training.interchange.tarball import ExportError
from training.rollout.envs import EnvRunner

pytest.importorskip("deepracer.logs")
from deepracer.logs import (  # noqa: E402 - only once the reader is known to be installed
    AnalysisUtils,
    DeepRacerLog,
    LogFolderType,
    TarFileHandler,
)

ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 3.0)]
EPISODES_PER_ITERATION = 2
CARS = 2
FOLDER = "u7-reader"
RUN = "training-20260101120000"
EVAL_STAMP = "20260102130000"
STEP_MS = 1000 / 15  # the simulator's step: 15 Hz, as SimApp's camera paces it


def _drive(episodes: int) -> tuple[list[LoggedIteration], list[list]]:
    """``episodes`` finished episodes of two cars side by side, logged in iterations of
    ``EPISODES_PER_ITERATION``; and the first car's rows of its first episode (an
    "evaluation" lap)."""
    envs = [RacingEnv("racecraft_oval", action_space=ACTIONS) for _ in range(CARS)]
    runner = EnvRunner(envs)
    log = TrainingLog(EPISODES_PER_ITERATION)
    rng = np.random.default_rng(5)
    runner.reset([11, 12])
    finished, first_lap = 0, []
    try:
        while finished < episodes:
            _, _, dones, infos = runner.step(rng.integers(0, len(ACTIONS), size=CARS))
            log.add_rows([info["trace"] for info in infos])
            if not first_lap or not TraceRow(*first_lap[-1]).done:
                first_lap.append(infos[0]["trace"][:-1])  # without the car's id
            for info in infos:
                if "episode_entry" in info:
                    log.add_entry(info["episode_entry"])
            finished += int(dones.sum())
    finally:
        runner.close()
    return log.take(final=True), first_lap


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """The logs download of a model with three iterations and one evaluation, on disk."""
    iterations, lap = _drive(3 * EPISODES_PER_ITERATION)
    files = {f"training-simtrace/{it.number}-iteration.csv": it.simtrace_csv().encode()
             for it in iterations}  # fmt: skip
    files[f"evaluation-{EVAL_STAMP}/evaluation-simtrace/0-iteration.csv"] = to_csv(
        [TraceRow(*row) for row in lap]
    ).encode()
    files["metrics/TrainingMetrics.json"] = json.dumps({"metrics": []}).encode()
    files["model/model_metadata.json"] = json.dumps(
        {"action_space": ACTIONS, "sensor": ["FRONT_FACING_CAMERA"],
         "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "version": "5"}
    ).encode()  # fmt: skip
    files["ip/hyperparameters.json"] = json.dumps(
        {"num_episodes_between_training": EPISODES_PER_ITERATION}
    ).encode()
    path = tmp_path_factory.mktemp("download") / f"{FOLDER}-logs.tar.gz"
    path.write_bytes(build_logs_archive(files, folder=FOLDER, training_run=RUN))
    return path


def test_the_archive_has_the_consoles_names(logs: Path) -> None:
    with tarfile.open(logs) as tar:
        names = set(tar.getnames())
    assert {n.split("/")[0] for n in names} == {FOLDER}
    assert f"{FOLDER}/sim-trace/training/{RUN}/training-simtrace/0-iteration.csv" in names
    evaluation = f"{FOLDER}/sim-trace/evaluation/{EVAL_STAMP}/evaluation-simtrace/0-iteration.csv"
    assert evaluation in names
    assert f"{FOLDER}/model/model_metadata.json" in names
    assert f"{FOLDER}/metrics/TrainingMetrics.json" in names
    assert not any(n.startswith(f"{FOLDER}/training-simtrace/") for n in names)


def test_tarfilehandler_reads_the_download_as_it_is(logs: Path) -> None:
    log = DeepRacerLog(filehandler=TarFileHandler(str(logs)))
    assert log.fh.type is LogFolderType.DROA_SOLUTION_LOGS
    log.load_training_trace()
    df = log.dataframe()
    assert sorted(df["iteration"].unique()) == [0, 1, 2]
    assert df["unique_episode"].nunique() == 3 * EPISODES_PER_ITERATION
    agg = AnalysisUtils.simulation_agg(df, secondgroup="unique_episode")
    assert (agg["time"] > 0).all() and (agg["steps"] > 1).all()

    log.load_evaluation_trace(force=True)
    evaluation = log.dataframe()
    assert list(evaluation["stream"].unique()) == [EVAL_STAMP]
    assert evaluation["episode"].nunique() == 1


def test_fsfilehandler_reads_the_extracted_folder(logs: Path, tmp_path: Path) -> None:
    with tarfile.open(logs) as tar:
        tar.extractall(tmp_path, filter="data")
    log = DeepRacerLog(model_folder=str(tmp_path / FOLDER))
    assert log.fh.type is LogFolderType.DROA_SOLUTION_LOGS
    log.load_training_trace()
    assert log.dataframe()["unique_episode"].nunique() == 3 * EPISODES_PER_ITERATION
    assert log.hyperparameters()["num_episodes_between_training"] == EPISODES_PER_ITERATION
    assert log.action_space() == ACTIONS
    log.load_evaluation_trace(force=True)
    assert list(log.dataframe()["stream"].unique()) == [EVAL_STAMP]


def test_wall_clock_and_pause_duration_hold_real_values(logs: Path) -> None:
    log = DeepRacerLog(filehandler=TarFileHandler(str(logs)))
    log.load_training_trace()
    df = log.dataframe()
    assert df["wall_clock"].notna().all() and df["pause_duration"].notna().all()
    assert (df["wall_clock"] > 1.7e9).all()  # seconds since the epoch, this decade
    for _, episode in df.groupby("unique_episode"):
        wall = episode.sort_values("steps")["wall_clock"].to_numpy()
        assert (np.diff(wall) > 0).all()  # strictly increasing, step by step
    # Training ends an episode at its first reset: no penalty is served, as on DeepRacer.
    assert (df["pause_duration"] == 0).all()


def test_stability_and_real_time_factor_are_plausible(logs: Path) -> None:
    log = DeepRacerLog(filehandler=TarFileHandler(str(logs)))
    log.load_training_trace()
    stats = log.stability.analyze()
    assert list(stats["iteration"]) == [0, 1, 2]
    for column in ("avg_ms", "max_ms", "p95_ms", "rtf", "train_time_s"):
        assert all(math.isfinite(v) for v in stats[column]), column
    # Steps of the simulated clock; the step after an episode's prepare row counts two (the
    # prepare row is the first step, stamped at the episode's start).
    assert ((stats["avg_ms"] > STEP_MS - 1) & (stats["avg_ms"] < STEP_MS * 1.25)).all()
    assert (stats["max_ms"] < 2 * STEP_MS + 1).all()
    assert (stats["rtf"] > 0).all()  # simulated seconds per wall-clock second
    assert (stats["train_time_s"] > 0).all()
    # The cars drive side by side and an iteration is logged once E episodes have finished, so
    # iterations overlap in wall time: the reader leaves their "policy update time" out rather
    # than report a negative one.
    timing = log.stability.analyze_timing()
    assert len(timing) == 3
    assert all(gap is None or gap >= 0 for gap in timing["policy_time_s"])

    log.load_evaluation_trace(force=True)
    evaluation = log.stability.analyze()
    assert len(evaluation) == 1 and evaluation["rtf"].iloc[0] > 0
    assert evaluation["avg_ms"].iloc[0] == pytest.approx(STEP_MS, rel=0.25)


def test_a_served_penalty_reads_as_simapps_pause_duration(tmp_path: Path) -> None:
    """An evaluation whose rules reset the car: the off-track step's row carries the penalty
    (SimApp's pause still to serve), every other row 0; the reader sees the clock jump."""
    env = RacingEnv("racecraft_oval", action_space=ACTIONS,
                    rules=RaceRules(resets=3, off_track_penalty_s=2.0))  # fmt: skip
    env.reset(seed=0)
    rows = []
    for _ in range(200):  # fast at full right lock drives off the track
        *_, info = env.step(1)
        rows.append(info["trace"].stamped())  # as the evaluation records it
        if info["reset"]:
            break
    for _ in range(5):  # respawned on the track, the lap goes on
        rows.append(env.step(2)[-1]["trace"].stamped())
    env.close()
    name = f"evaluation-{EVAL_STAMP}/evaluation-simtrace/0-iteration.csv"
    path = tmp_path / "logs.tar.gz"
    path.write_bytes(build_logs_archive({name: to_csv(rows).encode()}, folder=FOLDER,
                                        training_run=RUN))  # fmt: skip

    log = DeepRacerLog(filehandler=TarFileHandler(str(path)))
    log.load_evaluation_trace()
    df = log.dataframe().sort_values("steps")
    paused = df[df["pause_duration"] > 0]
    assert list(paused["episode_status"]) == ["off_track"]
    assert list(paused["pause_duration"]) == [2.0]
    assert (df.loc[df["pause_duration"] == 0, "episode_status"] != "off_track").all()
    jump = df["tstamp"].diff()[paused.index[0]]
    assert jump == pytest.approx(2.0 + STEP_MS / 1000, abs=0.002)
    assert (np.diff(df["wall_clock"].to_numpy()) > 0).all()


def test_every_stored_log_finds_its_place() -> None:
    """DeepRacer-for-Cloud's names in the store, and older evaluations' ``evaluation/<id>/``,
    move under ``sim-trace/``; the rest keep their names."""
    stored = {
        "training-simtrace/0-iteration.csv": b"t",
        f"evaluation-{EVAL_STAMP}/evaluation-simtrace/0-iteration.csv": b"e",
        "evaluation/17/evaluation-simtrace/0-iteration.csv": b"old",
        "metrics/EvaluationMetrics-20260102130000.json": b"{}",
        "reward_function.py": b"def reward_function(params): return 1.0\n",
    }
    assert logs_archive_names(stored, training_run=RUN) == {
        f"sim-trace/training/{RUN}/training-simtrace/0-iteration.csv": b"t",
        f"sim-trace/evaluation/{EVAL_STAMP}/evaluation-simtrace/0-iteration.csv": b"e",
        "sim-trace/evaluation/17/evaluation-simtrace/0-iteration.csv": b"old",
        "metrics/EvaluationMetrics-20260102130000.json": b"{}",
        "reward_function.py": b"def reward_function(params): return 1.0\n",
    }
    for folder, run in (("", RUN), (FOLDER, ""), ("a/b", RUN), (FOLDER, "..")):
        with pytest.raises(ExportError, match="bad folder name"):
            build_logs_archive(stored, folder=folder, training_run=run)
