"""Issue 22 on the command line: the reward validator (``python -m
training.rewards.validation``) and ``manage.py racecraft_create_model`` answer a source too deep
to check, or too long, with the same message as the web, exit non-zero and print no
traceback."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
from django.contrib.auth import get_user_model
from django.core.management import call_command
from django.core.management.base import CommandError

from training.models import RacingModel
from training.sandbox.static import SOURCE_TOO_LONG, TOO_DEEP

ROOT = Path(__file__).resolve().parents[3]
FN = "def reward_function(params):\n    return "
SOURCES = {
    "long_sum": (FN + "1.0" + " + 1" * 5000 + "\n", f"{TOO_DEEP}: ", None),
    "nested_lambdas": (FN + "(" + "lambda: " * 2000 + "1.0)\n", f"{TOO_DEEP}: ", 2),
    "ten_megabytes": (FN + "1.0\n" + "#" * 10_000_000, SOURCE_TOO_LONG, None),
}


def _validate(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "training.rewards.validation", str(path), "--track", "racecraft_oval"],  # noqa: E501
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip


@pytest.mark.parametrize("source, message, line", SOURCES.values(), ids=list(SOURCES))
def test_the_validator_prints_the_message_and_exits_1(
    tmp_path: Path, source: str, message: str, line: int | None
) -> None:
    path = tmp_path / "reward_function.py"
    path.write_text(source)
    out = _validate(path)
    assert out.returncode == 1, out.stderr[-2000:]
    assert "Traceback" not in out.stderr and "Traceback" not in out.stdout
    result = json.loads(out.stdout)
    (error,) = result["errors"]
    assert error["type"] == "SYNTAX_ERROR" and error["message"].startswith(message)
    assert error["line"] == line


@pytest.mark.django_db
@pytest.mark.parametrize("source, message, line", SOURCES.values(), ids=list(SOURCES))
def test_create_model_refuses_with_the_message(
    store_dir, tmp_path: Path, source: str, message: str, line: int | None
) -> None:
    get_user_model().objects.create_user("alice", password="pw-alice-123")
    path = tmp_path / "reward_function.py"
    path.write_text(source)
    args = ["--owner", "alice", "--name", "deep", "--reward", str(path), "--preset", "racing"]
    with pytest.raises(CommandError) as refused:
        call_command("racecraft_create_model", *args, stdout=io.StringIO(), stderr=io.StringIO())
    assert message in str(refused.value)
    assert not RacingModel.objects.exists()
