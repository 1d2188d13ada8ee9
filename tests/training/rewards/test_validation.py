"""Validation before a model is created: static errors, runtime checks on real tracks, the
examples, and the command line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from racing.tracks import TrackCatalog
from training.rewards.examples import EXAMPLES, example_source
from training.rewards.validation import SITUATIONS, situation_params, validate_reward_function
from training.sandbox import MAX_SOURCE_CHARS, SandboxLimits, check_source

TRACK = "racecraft_oval"
ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize(
    ("source", "kind", "line", "column", "text"),
    [
        ("def reward_function(params)\n    return 1\n", "SYNTAX_ERROR", 1, 28, "expected ':'"),
        (
            "import math\nimport os\n\ndef reward_function(p):\n    return 1\n",
            "IMPORT_ERROR",
            2,
            1,
            "'os'",
        ),
        (
            "def reward_function(p):\n    x = __import__('os')\n    return 1\n",
            "IMPORT_ERROR",
            2,
            9,
            "__import__",
        ),
        (
            "def reward_function(p):\n    return len(open('/etc/passwd').read())\n",
            "SYNTAX_ERROR",
            2,
            16,
            "'open'",
        ),
        (
            "import numpy as np\ndef reward_function(p):\n    return np.load('x')\n",
            "SYNTAX_ERROR",
            3,
            15,
            "'load'",
        ),
        ("def reward_function(p):\n    return ().__class__\n", "SYNTAX_ERROR", 2, 15, "__class__"),
        ("def reward(params):\n    return 1\n", "SYNTAX_ERROR", None, None, "reward_function"),
        ("def reward_function(a, b):\n    return 1\n", "TEST_FAILURE", 1, 1, "exactly one"),
        ("def reward_function(*params):\n    return 1\n", "TEST_FAILURE", 1, 1, "exactly one"),
    ],
)
def test_static_errors_are_structured(source, kind, line, column, text) -> None:
    err = check_source(source)[0]
    assert (err.type, err.line, err.column) == (kind, line, column), err
    assert text in err.message
    assert set(err.to_dict()) >= {"type", "message", "line", "column"}


def test_allowed_imports_pass_the_static_check() -> None:
    source = (
        "import math, random\nimport numpy as np\nimport scipy.spatial\n"
        "from scipy import interpolate\nfrom shapely.geometry import Point, Polygon\n"
        "from math import *\n\ndef reward_function(params):\n    return 1.0\n"
    )
    assert check_source(source) == []


def test_source_length_is_limited() -> None:
    source = "def reward_function(p):\n    return 1.0\n" + "#" * MAX_SOURCE_CHARS
    (err,) = check_source(source)
    assert err.type == "SYNTAX_ERROR" and "140,000" in err.message


def test_situations_come_from_the_simulator_on_the_real_track() -> None:
    track = TrackCatalog().load(TRACK)
    params = situation_params(track)
    assert len(params) == len(SITUATIONS) >= 6
    by_name = dict(zip(SITUATIONS, params, strict=True))
    assert by_name["off_track"]["is_offtrack"] or not by_name["off_track"]["all_wheels_on_track"]
    assert by_name["reversed"]["is_reversed"]
    assert by_name["with_objects"]["objects_location"]
    assert not by_name["mid_lap"]["objects_location"]
    assert by_name["start_line"]["waypoints"] == by_name["mid_lap"]["waypoints"]


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.id for e in EXAMPLES])
def test_the_examples_validate_and_run(example) -> None:
    result = validate_reward_function(example_source(example.id), TRACK)
    assert result.ok, result.errors
    assert set(result.rewards) == set(SITUATIONS)
    assert all(0 <= r <= 1e5 for r in result.rewards.values())
    assert (
        result.rewards["off_track"] < result.rewards["mid_lap"] or example.id == "object_avoidance"
    )
    assert result.layers["seccomp"].startswith(("active", "unavailable"))


@pytest.mark.slow  # 81 tracks since DeepRacer's are built in: about 2 s each on a loaded machine
def test_examples_run_on_every_track() -> None:
    source = example_source("object_avoidance")
    for track_id in TrackCatalog().ids():
        assert validate_reward_function(source, track_id).ok, track_id


def test_runtime_errors_carry_the_line_and_situation() -> None:
    source = (
        "def reward_function(params):\n"
        "    if params['is_offtrack'] or not params['all_wheels_on_track']:\n"
        "        return params['objects_location'][0][0]\n"
        "    return 1.0\n"
    )
    result = validate_reward_function(source, TRACK)
    (err,) = result.errors
    assert err.type == "TEST_FAILURE" and err.line == 3 and err.column == 16
    assert "situation 'off_track'" in err.message and "IndexError" in err.message
    assert "off_track" not in result.rewards and "mid_lap" in result.rewards


def test_a_hanging_situation_stops_validation_with_the_limit_per_call() -> None:
    source = (
        "def reward_function(params):\n"
        "    while params['is_reversed']:\n        pass\n    return 1.0\n"
    )
    result = validate_reward_function(source, TRACK, limits=SandboxLimits(per_call_seconds=0.5))
    (err,) = result.errors
    assert "situation 'reversed'" in err.message
    assert "took longer than 0.5 s per call" in err.message
    assert "later situations did not run" in err.message
    assert set(result.rewards) == set(SITUATIONS[: SITUATIONS.index("reversed")])


@pytest.mark.slow
def test_an_endless_loop_ends_after_one_call_of_five_seconds() -> None:
    source = "def reward_function(params):\n    while True:\n        pass\n"
    result = validate_reward_function(source, TRACK)
    # One call ran into the limit and nothing after it ran (before: one 5 s time-out for
    # every situation, about 35 s).
    (err,) = result.errors
    assert "took longer than 5 s per call" in err.message and not result.rewards


def test_an_error_in_every_situation_is_one_message_naming_them() -> None:
    source = "def reward_function(params):\n    x = params['nope']\n    return 1.0\n"
    (err,) = validate_reward_function(source, TRACK).errors
    assert err.message.startswith(f"in all {len(SITUATIONS)} test situations: ")
    assert "KeyError" in err.message and err.line == 2


def test_an_error_in_some_situations_lists_them() -> None:
    source = (
        "def reward_function(params):\n"
        "    if params['is_reversed'] or params['is_offtrack']:\n"
        "        return 1 / 0\n    return 1.0\n"
    )
    (err,) = validate_reward_function(source, TRACK).errors
    assert err.message.startswith("situations 'off_track', 'reversed': ")
    assert err.line == 3


def test_a_wrong_return_type_points_at_the_return() -> None:
    source = (
        "def reward_function(params):\n"
        "    if params['speed'] > 100:\n"
        "        return 2.0\n"
        "    return '1.0'\n"
    )
    (err,) = validate_reward_function(source, TRACK).errors
    assert err.type == "TEST_FAILURE" and err.line == 4 and "returned '1.0'" in err.message


def test_a_forbidden_call_is_a_permission_error() -> None:
    source = "import math\n\ndef reward_function(params):\n    return eval('1.0')\n"
    (err,) = validate_reward_function(source, TRACK).errors
    assert err.type == "IMPORT_ERROR" and err.line == 4
    assert "'eval' is not permitted" in err.message
    source = "import numpy as np\n\ndef reward_function(params):\n    return np.load('x')\n"
    (err,) = validate_reward_function(source, TRACK).errors
    assert err.type == "IMPORT_ERROR" and "'load' is not permitted" in err.message


def test_a_module_that_fails_to_load_is_reported_once() -> None:
    result = validate_reward_function(
        "raise ValueError('no')\n\ndef reward_function(p):\n    return 1\n", TRACK
    )
    (err,) = result.errors
    assert err.line == 1 and "ValueError" in err.message


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "training.rewards.validation", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )


def test_command_line_prints_json_and_exits_by_result(tmp_path: Path) -> None:
    good = tmp_path / "good.py"
    good.write_text(example_source())
    out = _cli(str(good), "--track", TRACK)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["ok"] is True
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\ndef reward_function(params):\n    return 1.0\n")
    out = _cli(str(bad), "--track", TRACK)
    assert out.returncode == 1
    (err,) = json.loads(out.stdout)["errors"]
    assert err["type"] == "IMPORT_ERROR" and err["line"] == 1
    assert _cli(str(bad), "--track", "no_such_track").returncode == 2
