"""Issue 22's holes in the Python guard, shut at run time too: what the static check cannot
see (names built at run time, ``type`` renamed or reached as ``type(type(x))``, bases computed
at run time) is refused by the guarded ``type`` and ``__build_class__``, with the line; and
messages that reach the user never show the server's code paths."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.training.sandbox.sandbox_support import real_params
from training.sandbox import SandboxCrashed, SandboxLimits, evaluate_reward, guard
from training.sandbox.classes import GuardedType
from training.sandbox.errors import RewardError, RewardFunctionError, hide_paths

HOSTILE = Path(__file__).parent / "hostile"
LIMITS = SandboxLimits(per_call_seconds=2.0, cpu_seconds=30)


def _run_unchecked(source: str, monkeypatch: pytest.MonkeyPatch) -> RewardError:
    """Load and call ``source`` with the restricted builtins but no static check (as if the
    check had missed it); the error it gives."""
    monkeypatch.setattr(guard, "check_source", lambda source: [])
    hb = memoryview(bytearray(32)).cast("q")
    with pytest.raises(RewardFunctionError) as caught:
        guard.RewardCallable(guard.load_reward_function(source), hb)({})
    return caught.value.error


RUN_TIME = {
    # The exploit, metaclass and match pattern with no dunder literal: refused at the
    # metaclass's class statement (line 11 of the file).
    "metaclass_match": (
        (HOSTILE / "match_metaclass_getattr_no_dunder_literal.py").read_text(),
        11,
        "may not derive from 'type'",
    ),
    "metaclass_keyword": (
        "class M:\n    pass\n\nclass C(metaclass=M):\n    pass\n\n"
        "def reward_function(params):\n    return 1.0\n",
        4,
        "class keywords (metaclass=)",
    ),
    "special_method_in_class_body": (
        "def reward_function(params):\n    class Spy:\n"
        "        def __getattr__(self, name):\n            return 1.0\n    return Spy().x\n",
        2,
        "defining '__getattr__' is not allowed",
    ),
    "type_renamed": (
        "def reward_function(params):\n    t = [type][0]\n    return t('C', (), {})\n",
        3,
        "three arguments",
    ),
    "type_of_type": (
        "def reward_function(params):\n    make = type(type(1))\n    return make('C', (), {})\n",
        3,
        "three arguments",
    ),
    "metaclass_base_at_run_time": (
        "def reward_function(params):\n    bases = [type(type(params))]\n"
        "    class Meta(*bases):\n        pass\n    return 1.0\n",
        3,
        "may not derive from 'type'",
    ),
}


@pytest.mark.parametrize("source, line, message", RUN_TIME.values(), ids=list(RUN_TIME))
def test_class_machinery_is_refused_at_run_time(
    source: str, line: int, message: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    error = _run_unchecked(source, monkeypatch)
    assert error.type == "TEST_FAILURE" and error.line == line
    assert message in error.message and "TypeError" in error.message


def test_the_guarded_type_answers_like_type_for_ordinary_code() -> None:
    builtins = guard.restricted_builtins()
    t = builtins["type"]
    assert t is GuardedType and repr(t) == "<class 'type'>"
    assert t(1) is int and t(np.float64(1)) is np.float64 and t([]) is list
    assert t(int) is t and t(t) is t and t(np.dtype) is t  # never the real type or a metaclass
    assert isinstance(int, t) and not isinstance(1, t) and issubclass(type, t)
    with pytest.raises(TypeError, match="three arguments"):
        t("C", (), {})
    assert builtins["__build_class__"] is not __builtins__["__build_class__"]


def test_a_metaclass_reached_as_an_attribute_is_the_guarded_type() -> None:
    assert guard._exposed(type) is GuardedType  # noqa: SLF001
    assert guard._exposed(type(np.dtype)) is GuardedType  # noqa: SLF001
    assert guard._exposed(np.dtype) is np.dtype  # noqa: SLF001 - an ordinary class stays


# ------------------------------------------------------------------ server paths (issue 22)
def test_paths_of_code_are_cut_to_the_file_name() -> None:
    text = (
        "/srv/racecraft/training/sandbox/oneshot.py:58: RuntimeWarning: x\n"
        '  File "/usr/lib/python3.11/json/decoder.py", line 3\n'
        "reward_function.py:3 and 1/2/3 and /sys/fs/cgroup/memory.max stay"
    )
    assert hide_paths(text) == (
        "oneshot.py:58: RuntimeWarning: x\n"
        '  File "decoder.py", line 3\n'
        "reward_function.py:3 and 1/2/3 and /sys/fs/cgroup/memory.max stay"
    )


def test_sandbox_errors_never_carry_server_paths() -> None:
    root = Path(guard.__file__).resolve().parent
    crashed = SandboxCrashed(f"the sandbox failed: ValueError at {root / 'oneshot.py'}:58")
    assert str(crashed) == "the sandbox failed: ValueError at oneshot.py:58"
    sent = {"type": "TEST_FAILURE", "message": f"boom in {root / 'child.py'}:212"}
    assert RewardError.from_dict(sent).message == "boom in child.py:212"
    exc = ValueError(f"cannot read {root / 'guard.py'}")
    assert guard.user_error(exc, 3, "reward_function").message == (
        "reward_function raised ValueError at step 3: cannot read guard.py"
    )


def test_a_warning_from_a_library_shows_no_server_path() -> None:
    source = (
        "import numpy as np\n\ndef reward_function(params):\n"
        "    empty = float(np.nan_to_num(np.mean([])))\n"
        "    big = np.float64(1e308) * 10\n"
        "    return empty + 1.0\n"
    )
    result = evaluate_reward(source, [real_params()], limits=LIMITS)
    assert result.errors == [] and result.outcomes[0].value == 1.0
    assert "RuntimeWarning: Mean of empty slice" in result.output
    # A warning in the user's own code keeps the user's file and line.
    assert "reward_function.py:5: RuntimeWarning: overflow" in result.output
    assert "/" not in result.output, result.output  # no path of ours or of a library
