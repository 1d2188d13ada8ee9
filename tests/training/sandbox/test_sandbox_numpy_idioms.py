"""Issue 52: a reward function written with the community's numpy idioms returns its reward
through the command line, the Validate service and a sandboxed rollout, never "import of
'numpy._core._methods' is not allowed".

numpy imports its own modules lazily from C (``arr.mean()`` imports ``numpy._core._methods``,
``print(arr)`` ``numpy._core.arrayprint``); ``PyImport_Import`` finds ``__import__`` in the
builtins of the calling frame, which are the racer's. The guard tells those imports from the
racer's ``import`` statements by the instruction the racer's frame stands on, so the racer's
statements are checked as before, and ``__import__`` called any other way (a library's C code,
or a racer who got hold of it) loads only an allowed library's modules and returns nothing.

The sandbox cases run in fresh processes: in this test process numpy has long cached its
lazy imports, so an in-process run would not reach the guard's ``__import__`` at all.
"""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from racing.tracks import TrackCatalog
from training.rewards.validation import SITUATIONS, situation_params, validate_reward_function
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import LocalVecEnv, SandboxedVecEnv
from training.sandbox import check_source, guard
from training.sandbox.errors import RewardError, RewardFunctionError

ROOT = Path(__file__).resolve().parents[3]
TRACK_ID = "racecraft_oval"
HOSTILE = Path(__file__).parent / "hostile"

#: A reward as racers share them: the waypoints as an array, the nearest one by
#: ``np.linalg.norm(...).argmin()``, reductions as methods and as functions, a printed array.
IDIOMS = """
import math

import numpy as np


def reward_function(params):
    waypoints = np.array(params["waypoints"])
    car = np.array([params["x"], params["y"]])
    distances = np.linalg.norm(waypoints - car, axis=1)
    nearest = int(distances.argmin())
    ahead = waypoints[(nearest + np.arange(0, 6)) % len(waypoints)]
    segments = np.diff(ahead, axis=0)
    headings = np.degrees(np.arctan2(segments[:, 1], segments[:, 0]))
    turns = np.abs((np.diff(headings) + 180.0) % 360.0 - 180.0)
    along = np.cumsum(np.linalg.norm(segments, axis=1))
    speeds = np.array([params["speed"], 1.0, 2.0, 3.0])
    print("speeds", speeds.round(2))
    reward = 1.0
    reward += 0.1 * speeds.mean() + 0.01 * speeds.sum() + 0.01 * speeds.max()
    reward += 0.1 * float(np.mean(np.clip(turns, 0.0, 90.0))) / 90.0
    reward += 0.01 * np.std(speeds) + 0.001 * np.percentile(distances, 90)
    reward += 0.001 * along[-1] + 0.001 * int(np.argmin(distances)) / len(waypoints)
    reward -= 0.01 * min(float(distances.min()), 1.0)
    reward += 0.001 * math.cos(math.radians(params["heading"]))
    if not params["all_wheels_on_track"]:
        reward *= 0.5
    return float(reward)
"""

#: The other allowed libraries' idioms: scipy's KD-trees, interpolation, filters and
#: statistics, shapely's geometry, the random module.
OTHER_LIBRARIES = """
import random

import numpy as np
from scipy import interpolate, signal, spatial, stats
from shapely.geometry import LineString, Point, Polygon


def reward_function(params):
    waypoints = np.array(params["waypoints"])
    here = [params["x"], params["y"]]
    gap, _ = spatial.cKDTree(waypoints).query(here)
    gap += spatial.KDTree(waypoints).query(here)[0]
    line = LineString(waypoints)
    car = Point(*here)
    print(car, Polygon(waypoints[:3]).area)
    along = line.project(car) / line.length + line.distance(car)
    x_at = float(interpolate.interp1d(np.arange(len(waypoints)), waypoints[:, 0])(1.5))
    smooth = signal.savgol_filter(waypoints[:, 0], 5, 2).mean()
    spread = np.nanmean(stats.zscore(waypoints[:, 1]))
    spread += spatial.distance.cdist([here], [here]).sum()
    random.seed(1)
    return float(1.0 + 0.001 * (gap + along + x_at + smooth + spread + random.random()))
"""


def unguarded(source: str) -> Any:
    """``source``'s reward_function run as plain Python in this process (the expected values);
    its prints are swallowed."""
    namespace: dict[str, Any] = {}
    exec(compile(source, "expected.py", "exec"), namespace)  # noqa: S102 - our own test source
    fn = namespace["reward_function"]

    def call(params: dict) -> float:
        with contextlib.redirect_stdout(io.StringIO()):
            return fn(guard.copy_params(params))

    return call


def expected_rewards(source: str = IDIOMS) -> dict[str, float]:
    params = situation_params(TrackCatalog().load(TRACK_ID))
    call = unguarded(source)
    return {name: call(p) for name, p in zip(SITUATIONS, params, strict=True)}


def test_the_idioms_pass_the_static_check() -> None:
    assert check_source(IDIOMS) == []
    assert len(set(expected_rewards().values())) > 1  # the reward depends on the params


def test_the_command_line_validator_returns_the_rewards(tmp_path: Path) -> None:
    path = tmp_path / "reward_function.py"
    path.write_text(IDIOMS)
    out = subprocess.run(
        [sys.executable, "-m", "training.rewards.validation", str(path), "--track", TRACK_ID],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    result = json.loads(out.stdout)
    assert result["ok"] is True and result["errors"] == []
    assert result["rewards"] == pytest.approx(expected_rewards(), rel=1e-12)
    assert "speeds [" in result["output"]  # print(array) works too (numpy._core.arrayprint)


@pytest.mark.slow
def test_the_validate_service_returns_the_rewards() -> None:
    from training.services import rewards

    result = rewards.reward_validation_run(source=IDIOMS, track_id=TRACK_ID, direction="native")
    assert result["ok"] is True, result["errors"]
    assert result["rewards"] == pytest.approx(expected_rewards(), rel=1e-12)


@pytest.mark.parametrize("source", [IDIOMS, OTHER_LIBRARIES], ids=["numpy", "scipy_shapely"])
def test_validate_reward_function_returns_the_rewards(source: str) -> None:
    assert check_source(source) == []
    result = validate_reward_function(source, TRACK_ID)
    assert result.ok, result.errors
    assert result.rewards == pytest.approx(expected_rewards(source), rel=1e-12)


@pytest.mark.slow
def test_a_sandboxed_rollout_returns_the_rewards_the_trusted_one_does() -> None:
    """The same seed and actions in a sandboxed worker (the racer's code under the guard) and
    in this process (plain Python): the same rewards, step by step."""
    actions = [{"steering_angle": a, "speed": s} for a in (-30, 0, 30) for s in (1.0, 2.0)]
    spec = EnvSpec(track=TRACK_ID, action_space=actions)
    chosen = np.random.default_rng(5).integers(len(actions), size=(40, 2))
    got = []
    for venv in (SandboxedVecEnv(spec, 2, IDIOMS, num_workers=1), None):
        venv = venv or LocalVecEnv(spec, 2, unguarded(IDIOMS))
        try:
            venv.seed(3)
            venv.reset()
            got.append(np.array([venv.step(step)[1] for step in chosen]))
        finally:
            venv.close()
    sandboxed, trusted = got
    assert sandboxed.shape == (40, 2) and np.all(sandboxed > 0)
    np.testing.assert_allclose(sandboxed, trusted, rtol=1e-6)
    assert len(np.unique(sandboxed)) > 10  # rewards of real steps, not one constant


# --- the racer's own imports are still checked at run time -------------------------------


def _run_unchecked(source: str, monkeypatch: pytest.MonkeyPatch) -> RewardError | float:
    """Load and call ``source`` with the restricted builtins but no static check (as if the
    check had missed it): its reward, or its error."""
    monkeypatch.setattr(guard, "check_source", lambda source: [])
    hb = memoryview(bytearray(32)).cast("q")
    try:
        return guard.RewardCallable(guard.load_reward_function(source), hb)({})
    except RewardFunctionError as exc:
        return exc.error


FN = "import numpy as np\n\ndef reward_function(params):\n    np.array([1.0, 2.0]).mean()\n"
#: A racer's import statement the static check would refuse, and the module it names.
STATEMENTS = {
    "private_module_after_the_lazy_import": (FN + "    import numpy._core._methods\n",
                                             "numpy._core._methods"),
    "from_private_package": (FN + "    from numpy._core import _methods\n", "numpy._core"),
    "import_as": (FN + "    import numpy._core._methods as m\n", "numpy._core._methods"),
    "os_in_a_function": (FN + "    import os\n", "os"),
    "refused_submodule": (FN + "    import numpy.lib.format\n", "numpy.lib.format"),
    "relative": (FN + "    from . import guard\n", ""),
    # More than 256 names: the statement's IMPORT_NAME carries an EXTENDED_ARG before it.
    "after_many_names": ("".join(f"n{i} = {i}\n" for i in range(300))
                         + "import os\n\ndef reward_function(params):\n    return 1.0\n", "os"),
}  # fmt: skip


@pytest.mark.parametrize("source, name", STATEMENTS.values(), ids=list(STATEMENTS))
def test_the_racers_import_statements_are_still_checked(
    source: str, name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    error = _run_unchecked(source, monkeypatch)
    assert isinstance(error, RewardError), error
    assert f"import of '{name}" in error.message and "is not allowed" in error.message
    assert error.type == "IMPORT_ERROR" or "raised ImportError" in error.message, error


def test_the_many_names_case_really_has_an_extended_arg() -> None:
    import dis

    code = compile(STATEMENTS["after_many_names"][0], "x", "exec")
    (imp,) = [i for i in dis.get_instructions(code) if i.opname == "IMPORT_NAME"]
    assert imp.arg > 255  # so the instruction before it is an EXTENDED_ARG


def test_allowed_import_statements_still_work(monkeypatch: pytest.MonkeyPatch) -> None:
    source = (
        "from math import *\n\ndef reward_function(params):\n    import math\n"
        "    from numpy import linalg\n    import numpy.linalg as la\n"
        "    return float(la.norm([3.0, 4.0]) + linalg.norm([0.0, 1.0]) + sqrt(4.0))\n"
    )
    assert _run_unchecked(source, monkeypatch) == 8.0


# --- the guard's __import__ in a racer's hands gives nothing -------------------------------


def test_a_forged_call_with_a_librarys_globals_gets_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The static check refuses ``__builtins__`` and ``__globals__``; without it, a racer
    reaches the guard's ``__import__`` and numpy's own globals, and calls it as a library
    would: every call returns None, and a module outside the libraries is not even loaded."""
    source = (HOSTILE / "lazy_import_forged_globals.py").read_text()
    assert sys.modules.get("this") is None  # "this" prints on import: never loaded here
    assert _run_unchecked(source, monkeypatch) == 1.0
    assert "this" not in sys.modules


def test_a_direct_call_loads_only_a_librarys_modules_and_returns_none() -> None:
    imp = guard.restricted_builtins()["__import__"]
    assert imp("os") is None  # loaded already: nothing runs, nothing comes back
    assert imp("numpy._core._methods", {"__name__": "numpy"}) is None
    for name, kwargs in [
        ("this", {}),  # a module no library has loaded
        ("numpy.f2py.never_there", {}),  # under a refused submodule
        ("numpy", {"fromlist": ("lib",)}),  # PyImport_Import passes no fromlist
        ("numpy", {"level": 1}),
    ]:
        with pytest.raises(ImportError, match="is not allowed"):
            imp(name, **kwargs)

    class Name(str):
        __hash__ = str.__hash__

    with pytest.raises(ImportError):
        imp(Name("os"))  # a str subclass could answer `in sys.modules` as it likes
    assert "this" not in sys.modules
