"""The command line as a new user meets it: no PyBullet banner, track ids in --help and in
the error for an unknown one, an example model_metadata.json, a progress line that never
looks stuck, the number of actions."""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from training.management import progress
from training.management.progress import ProgressBar

ROOT = Path(__file__).resolve().parents[3]


def _manage(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "manage.py", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)  # fmt: skip


def test_help_has_no_banner_and_lists_the_tracks_and_an_example() -> None:
    out = _manage("racecraft_create_model", "--help")
    assert out.returncode == 0, out.stderr
    assert "pybullet build time" not in out.stdout + out.stderr
    assert "racecraft_oval" in out.stdout and "racecraft_summit" in out.stdout
    example = re.search(r"\n  (\{\n.*?\n  \})\n", out.stdout, re.S)[1]
    from training.rl.metadata import parse_metadata

    meta = parse_metadata(json.dumps(json.loads(example)).encode())
    assert len(meta.actions.to_metadata()) == 3


def test_an_unknown_track_lists_the_choices() -> None:
    out = _manage("racecraft_evaluate", "1", "--track", "no_such_track")
    assert out.returncode == 2
    assert "invalid choice: 'no_such_track'" in out.stderr and "racecraft_oval" in out.stderr
    assert "pybullet build time" not in out.stdout + out.stderr


def test_evaluate_explains_why_it_has_no_seed() -> None:
    out = _manage("racecraft_evaluate", "--help")
    assert "There is no --seed" in " ".join(out.stdout.split())


def test_the_log_bar_writes_a_line_when_time_passes(monkeypatch) -> None:
    clock = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    out = io.StringIO()
    bar = ProgressBar(out, tty=False)
    bar.update(0.0, "00:00/10:00  iteration 1 running")
    for second in range(1, 40):
        clock[0] = float(second)
        bar.update(second / 600, f"00:{second:02d}/10:00  iteration 1 running  0 episodes")
    lines = out.getvalue().splitlines()
    assert 3 <= len(lines) <= 4  # at 0 s, then every 15 s though 10% is far away


@pytest.mark.django_db
def test_training_progress_names_the_running_iteration(settings, tmp_path) -> None:
    from tests.console.conftest import make_model
    from training.management.cli import action_summary, training_progress
    from training.models import JobStatus, TrainingJob

    settings.STORE_DIR = tmp_path / "store"
    from django.contrib.auth import get_user_model

    owner = get_user_model().objects.create_user("joe", password="x-long-pass-1")
    model = make_model(owner, hyperparameters={"num_episodes_between_training": 4})
    job = TrainingJob.objects.create(model=model, max_minutes=2, status=JobStatus.IN_PROGRESS)
    _, text = training_progress(job)
    assert "iteration 1 running (4 episodes + update)" in text and "0 episodes" in text
    assert action_summary(model) == "3 discrete actions"
