"""The ``racecraft_*`` management commands: a model from DeepRacer's files, trained and
evaluated in the command's own process (Ctrl-C included), exported and imported again; clear
errors for bad files and unknown users; the progress bar. (Alice owns things; Bob must never
touch them.)"""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
from django.core.management import call_command
from django.core.management.base import CommandError

from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from training import services
from training.management import cli
from training.management.progress import ProgressBar, render_bar
from training.models import EvaluationJob, JobStatus, RacingModel, TrainingJob
from training.services.model_files import TRAINING_PARAMS
from training.store import get_store, keys_for

ROOT = Path(__file__).resolve().parents[3]
TINY_HYPERPARAMETERS = {"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32}


@pytest.fixture
def files(tmp_path) -> dict[str, Path]:
    """DeepRacer's three files, as a user has them on disk."""
    folder = tmp_path / "deepracer"
    folder.mkdir()
    metadata = {
        "action_space": [dict(action, index=i) for i, action in enumerate(ACTIONS)],
        "sensor": ["FRONT_FACING_CAMERA"],
        "neural_network": "RACECRAFT_LEAN_CNN",
        "training_algorithm": "clipped_ppo",
        "action_space_type": "discrete",
        "version": "5",
    }
    paths = {
        "reward": folder / "reward_function.py",
        "metadata": folder / "model_metadata.json",
        "hyperparameters": folder / "hyperparameters.json",
    }
    paths["reward"].write_text(REWARD)
    paths["metadata"].write_text(json.dumps(metadata))
    paths["hyperparameters"].write_text(json.dumps(TINY_HYPERPARAMETERS))
    return paths


def run(name: str, *args: str) -> str:
    out = io.StringIO()
    call_command(name, *args, stdout=out, stderr=io.StringIO())
    return out.getvalue()


def create_args(files: dict[str, Path], *extra: str, name: str = "oval-runner") -> list[str]:
    return ["--owner", "alice", "--name", name, "--reward", str(files["reward"]),
            "--metadata", str(files["metadata"]), "--hyperparameters",
            str(files["hyperparameters"]), "--track", "racecraft_oval", *extra]  # fmt: skip


# ------------------------------------------------------------------------------ create
@pytest.mark.django_db
def test_create_reads_deepracer_files(store_dir, alice, files):
    out = run("racecraft_create_model", *create_args(files, "--minutes", "3", "--seed", "7"))
    model = RacingModel.objects.get(owner=alice, name="oval-runner")
    assert f"Created model {model.pk}: oval-runner" in out
    assert model.action_space == [dict(a, index=i) for i, a in enumerate(ACTIONS)]
    assert model.sensors == ["FRONT_FACING_CAMERA"] and model.algorithm == "clipped_ppo"
    assert model.neural_network == "RACECRAFT_LEAN_CNN" and model.track_id == "racecraft_oval"
    assert model.hyperparameters["num_epochs"] == 3 and model.hyperparameters["lr"] == 0.0003
    assert model.max_minutes == 3 and model.seed == 7
    assert get_store().get_bytes(keys_for(model.pk).reward_function).decode() == REWARD

    quiet = run("racecraft_create_model", *create_args(files, "-v", "0", name="second"))
    assert quiet.strip() == str(RacingModel.objects.get(name="second").pk)


@pytest.mark.parametrize(
    "target, content, message",
    [
        ("metadata", "{not json", "model_metadata.json: model_metadata.json: is not valid JSON"),
        ("metadata", '{"sensor": ["FRONT_FACING_CAMERA"]}', "action_space: is required"),
        ("metadata", '{"action_space": [], "sensor": ["LIDAR"]}', "action_space"),
        ("hyperparameters", "[1, 2", "hyperparameters.json is not valid JSON"),
        ("hyperparameters", "[1, 2]", "must hold a JSON object"),
        ("hyperparameters", '{"batch_size": 100}', "batch_size: must be one of"),
        ("reward", b"\xff\xfe", "is not UTF-8 text"),
    ],
)
@pytest.mark.django_db
def test_bad_files_are_refused_clearly(store_dir, alice, files, target, content, message):
    path = files[target]
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(CommandError, match=message):
        run("racecraft_create_model", *create_args(files))
    assert not RacingModel.objects.exists()


@pytest.mark.django_db
def test_a_missing_file_and_a_reward_with_errors(store_dir, alice, files):
    files["reward"].unlink()
    with pytest.raises(CommandError, match="cannot read the reward function .*No such file"):
        run("racecraft_create_model", *create_args(files))
    files["reward"].write_text(
        "def reward_function(params):\n    x = params['speed'\n    return x\n"
    )
    with pytest.raises(CommandError) as err:
        run("racecraft_create_model", *create_args(files))
    assert "the reward function was rejected" in str(err.value)
    assert "line 2: SYNTAX_ERROR: " in str(err.value)
    assert not RacingModel.objects.exists()


@pytest.mark.django_db
def test_unknown_users_and_other_peoples_models_are_refused(store_dir, alice, bob, files):
    args = create_args(files)
    args[1] = "zed"
    with pytest.raises(CommandError, match="there is no user named 'zed'"):
        run("racecraft_create_model", *args)
    model = services.model_create(owner=alice, name="m1", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False)  # fmt: skip
    for command in ("racecraft_train", "racecraft_evaluate"):
        with pytest.raises(CommandError, match=f"there is no model {model.pk} owned by 'bob'"):
            run(command, str(model.pk), "--owner", "bob")
    with pytest.raises(CommandError, match="there is no model 999"):
        run("racecraft_export", "999", "--car", "x.tar.gz")
    with pytest.raises(CommandError, match="train this model before evaluating it"):
        run("racecraft_evaluate", str(model.pk))
    with pytest.raises(CommandError, match="no trained checkpoint yet"):
        run("racecraft_export", str(model.pk), "--virtual", "x.tar.gz")
    assert not TrainingJob.objects.exists() and not EvaluationJob.objects.exists()


def test_a_failed_command_exits_with_code_1():
    proc = subprocess.run(
        [sys.executable, "manage.py", "racecraft_export", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 1
    assert "say what to export: --car PATH, --onnx PATH, --virtual PATH, --logs PATH" in proc.stderr


# ------------------------------------------------------------------------------ queue mode
@pytest.mark.django_db
def test_queue_mode_follows_the_job_and_ctrl_c_stops_following(store_dir, alice, monkeypatch):
    # In a test transaction, on_commit never fires: the job stays queued, nobody runs it.
    model = services.model_create(owner=alice, name="m1", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False)  # fmt: skip

    def ctrl_c(seconds: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "pause", ctrl_c)
    out = run("racecraft_train", str(model.pk), "--queue")
    job = TrainingJob.objects.get(model=model)
    assert f"Training job {job.pk} of model {model.pk} (m1): queued for a worker" in out
    assert f"Stopped following job {job.pk}; it goes on in the worker" in out
    assert job.status == JobStatus.QUEUED  # following stopped, not the job

    with pytest.raises(CommandError, match="this model is busy"):
        run("racecraft_train", str(model.pk), "--queue")
    services.job_stop(job=job, user=alice)

    def cancel(seconds: float) -> None:
        queued = TrainingJob.objects.get(model=model, status=JobStatus.QUEUED)
        services.job_stop(job=queued, user=alice)

    monkeypatch.setattr(cli, "pause", cancel)
    with pytest.raises(CommandError, match=r"training job \d+ ended Canceled"):
        run("racecraft_train", str(model.pk), "--queue")
    assert TrainingJob.objects.filter(model=model, status=JobStatus.CANCELED).count() == 2


@pytest.mark.django_db
def test_giving_up_marks_the_job_failed(monkeypatch, store_dir, alice):
    model = services.model_create(owner=alice, name="m1", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False)  # fmt: skip
    job = TrainingJob.objects.create(model=model, max_minutes=1, status=JobStatus.IN_PROGRESS)

    def exit_now(code: int) -> None:
        raise SystemExit(code)

    monkeypatch.setattr(cli, "exit_now", exit_now)
    with pytest.raises(SystemExit) as exited:
        cli.give_up(job)
    assert exited.value.code == 1
    job.refresh_from_db()
    assert job.status == JobStatus.FAILED and "abandoned" in job.error


# ------------------------------------------------------------------------------ progress
def test_the_bar_redraws_in_place_on_a_terminal():
    out = io.StringIO()
    bar = ProgressBar(out, tty=True, width=10)
    bar.update(0.45, "iteration 12  eval 80.0%  best 100.0%")
    bar.update(0.5, "x")
    bar.close()
    text = out.getvalue()
    assert text.startswith("\r[####......]  45%  iteration 12  eval 80.0%  best 100.0%")
    assert "\r[#####.....]  50%  x" in text and text.endswith("\n")
    assert "\n" not in text[:-1]  # one line, redrawn


def test_the_bar_writes_a_line_every_tenth_elsewhere():
    out = io.StringIO()
    bar = ProgressBar(out, tty=False)
    for i in range(101):
        bar.update(i / 200, f"step {i}")  # up to 50%
    bar.close()
    lines = out.getvalue().splitlines()
    assert [line.split("]")[1].split("%")[0].strip() for line in lines] == [
        "0", "10", "20", "30", "40", "50",
    ]  # fmt: skip
    assert lines[-1].endswith("step 100")
    assert render_bar(1.7, width=4) == "[####] 100%"


def test_results_table():
    job = EvaluationJob(laps=3, results={"laps": [
        {"trial": 1, "time_s": 65.4321, "progress": 100.0, "status": "lap_complete",
         "off_tracks": 2, "off_track_penalty_s": 4.0, "crashes": 0, "crash_penalty_s": 0.0,
         "resets": 2},
        {"trial": 2, "time_s": 12.0, "progress": 23.456, "status": "time_up",
         "off_tracks": 0, "off_track_penalty_s": 0.0, "crashes": 1, "crash_penalty_s": 5.0,
         "resets": 1},
    ]})  # fmt: skip
    lines = cli.results_table(job).splitlines()
    assert lines[0].split() == ["Trial", "Time", "Progress", "Status", "Off-tracks", "Crashes",
                                "Resets"]  # fmt: skip
    assert lines[1].split() == ["1", "01:05.432", "100.0%", "Lap", "complete", "2", "(+4", "s)",
                                "0", "(+0", "s)", "2"]  # fmt: skip
    assert "00:12.000" in lines[2] and "23.5%" in lines[2] and "Time Up" in lines[2]


# ------------------------------------------------------------------------------ a model's life
@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_create_train_evaluate_export_import(store_dir, alice, files, tmp_path, monkeypatch):
    # A stop condition far beyond the first iteration however loaded the machine is: the job
    # must end because of the Ctrl-C below, never the time limit.
    run("racecraft_create_model", *create_args(files, "--minutes", "30", "--seed", "1"))
    model = RacingModel.objects.get(name="oval-runner")

    # Ctrl-C once the first iteration is stored: the job stops cleanly and keeps it.
    pressed = []

    def ctrl_c_after_first_iteration(seconds: float) -> None:
        if not pressed and TrainingJob.objects.filter(model=model, iterations__gte=1).exists():
            pressed.append(True)
            raise KeyboardInterrupt
        cli.time.sleep(seconds)

    monkeypatch.setattr(cli, "pause", ctrl_c_after_first_iteration)
    out = run("racecraft_train", str(model.pk))
    job = TrainingJob.objects.get(model=model)
    assert pressed, out
    assert job.status == JobStatus.COMPLETED and job.stopped_by == "user", out
    assert "Stopping: the job ends at its next safe point" in out
    assert re.search(r"iteration \d+ running  \d+ episodes  eval \d+\.\d%  best \d+\.\d%", out), out
    assert "Completed (stopped by you)" in out
    assert job.worker.startswith("cli-")
    model.refresh_from_db()
    assert model.status == RacingModel.Status.READY and model.has_checkpoint
    assert get_store().exists(keys_for(model.pk).best)

    # Evaluate; stop after a few seconds so an untrained car need not drive three laps.
    started = []

    def ctrl_c_after_a_while(seconds: float) -> None:
        started.append(seconds)
        if len(started) == 12:
            raise KeyboardInterrupt
        cli.time.sleep(seconds)

    monkeypatch.setattr(cli, "pause", ctrl_c_after_a_while)
    out = run("racecraft_evaluate", str(model.pk), "--laps", "3")
    evaluation = EvaluationJob.objects.get(model=model)
    assert evaluation.status == JobStatus.COMPLETED, out
    assert re.search(r"Trial\s+Time\s+Progress\s+Status\s+Off-tracks\s+Crashes\s+Resets", out), out
    assert f"Evaluation {evaluation.pk}: Completed" in out
    assert len(evaluation.lap_rows) >= 1

    folder = tmp_path / "exports"
    folder.mkdir()
    out = run("racecraft_export", str(model.pk), "--owner", "alice", "--car", str(folder),
              "--virtual", str(folder / "virtual.tar.gz"), "--logs", str(folder))  # fmt: skip
    assert out.count("Wrote the ") == 3
    expected = {
        "physicalmodel-oval-runner.tar.gz": {"model.pb", "model_metadata.json"},
        "virtual.tar.gz": {"reward_function.py"},
        "oval-runner-logs.tar.gz": set(),
    }
    for name, members in expected.items():
        with tarfile.open(folder / name, "r:gz") as tar:
            names = {Path(n).name for n in tar.getnames()}
        assert members <= names and names, name

    out = run("racecraft_import", str(folder / "virtual.tar.gz"), "--owner", "alice",
              "--name", "oval-runner-copy")  # fmt: skip
    copy = RacingModel.objects.get(name="oval-runner-copy")
    assert f"Imported model {copy.pk}" in out
    assert copy.imported and copy.has_checkpoint and copy.action_space == model.action_space
    assert RacingModel.objects.filter(owner=alice).count() == 2


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_a_model_set_to_stop_when_ready_stops_at_its_first_clean_evaluation(
    store_dir, alice, files
):
    """The real loop, workers and sandbox: on the oval (8 episodes an update, seed 0, the
    console's five evaluation laps from spread starts) the first evaluation that completes
    every lap comes within a few thousand steps; the job ends there, "ready", with that
    iteration as the best checkpoint, long before its 30 minutes."""
    eight = {**TINY_HYPERPARAMETERS, "num_episodes_between_training": 8}
    files["hyperparameters"].write_text(json.dumps(eight))
    out = run("racecraft_create_model", *create_args(
        files, "--minutes", "30", "--seed", "0", "--stop-when-ready", "1"))  # fmt: skip
    model = RacingModel.objects.get(name="oval-runner")
    assert model.stop_when_ready == 1
    assert "stop: 30 min, or when ready: an evaluation completes every lap" in out
    params = get_store().get_bytes(f"{keys_for(model.pk).prefix}{TRAINING_PARAMS}").decode()
    assert 'RACECRAFT_STOP_WHEN_READY: "1"' in params

    out = run("racecraft_train", str(model.pk))
    job = TrainingJob.objects.get(model=model)
    assert job.status == JobStatus.COMPLETED and job.stopped_by == "ready", out
    assert "Completed (ready: its evaluations completed every lap)" in out
    points = list(job.iterations_set.order_by("iteration"))
    last = points[-1]
    assert (last.eval_progress, last.eval_laps_completed, last.is_best) == (100.0, 5, True)
    assert all(p.eval_laps_completed < 5 for p in points[:-1])  # the first clean one
    assert job.best_iteration == last.iteration == job.iterations
    assert job.elapsed_seconds < 30 * 60
