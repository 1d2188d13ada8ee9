"""Attribute access however it is spelled (match patterns, format strings, the getattr family)
is checked like ``a.b``; refused modules are refused when reached as attributes too."""

from __future__ import annotations

import pytest

from training.sandbox import RewardFunctionError, check_source
from training.sandbox.guard import RewardCallable, load_reward_function

HEAD = "import math\nimport numpy as np\n\ndef reward_function(params):\n"

REFUSED_STATICALLY = {
    "class_pattern": (
        "    match params:\n        case object(__class__=c):\n            return 1.0\n",
        "'__class__' (in a class pattern)",
    ),
    "class_pattern_private": (
        "    match params:\n        case dict(_x=c):\n            return 1.0\n",
        "'_x' (in a class pattern)",
    ),
    "mapping_pattern": (
        "    match params:\n        case {'__class__': c}:\n            return 1.0\n",
        "'__class__' (in a mapping pattern)",
    ),
    "capture_dunder": (
        "    match params:\n        case __builtins__:\n            return 1.0\n",
        "use of '__builtins__'",
    ),
    "mapping_rest_dunder": (
        "    match params:\n        case {**__builtins__}:\n            return 1.0\n",
        "use of '__builtins__'",
    ),
    "format_field": (
        "    return '{0.__class__}'.format(params)\n",
        "'__class__' (in a format string)",
    ),
    "format_after_index": (
        "    return '{0[x].__globals__}'.format(params)\n",
        "'__globals__' (in a format string)",
    ),
    "format_nested_spec": (
        "    return '{0:{1.__init__}}'.format(1, params)\n",
        "'__init__' (in a format string)",
    ),
    "format_map_field": (
        "    return '{p.__class__}'.format_map({'p': params})\n",
        "'__class__' (in a format string)",
    ),
    "format_on_a_variable": (
        "    t = '{0.' + '__class__}'\n    return t.format(params)\n",
        "'.format' is allowed on a string literal only",
    ),
    "str_format_unbound": (
        "    return str.format('{0}', params)\n",
        "'.format' is allowed on a string literal only",
    ),
    "getattr_literal": ("    return getattr(params, '__class__')\n", "'__class__'"),
    "hasattr_literal": ("    return hasattr(params, '__dict__')\n", "'__dict__'"),
    "setattr_literal": ("    setattr(np, 'load', None)\n", "'load'"),
    "delattr_literal": ("    delattr(math, '_x')\n", "'_x'"),
    "attrgetter": ("    return np.core.operator.attrgetter('x')\n", "'attrgetter'"),
    "numpy_lib_format": ("    return np.lib.format.read_array\n", "module 'numpy.lib.format'"),
    "numpy_rec": ("    return np.rec.array\n", "module 'numpy.rec'"),
    "numpy_memmap": ("    return np.memmap\n", "'memmap'"),
    "numpy_npyio": ("    return np.lib.npyio.load\n", "'npyio'"),
    "numpy_ctypeslib": ("    return np.ctypeslib\n", "'ctypeslib'"),
}


@pytest.mark.parametrize("body, message", REFUSED_STATICALLY.values(), ids=list(REFUSED_STATICALLY))
def test_refused_statically(body: str, message: str) -> None:
    errors = check_source(HEAD + body)
    assert errors, body
    assert errors[0].type == "SYNTAX_ERROR" and errors[0].line is not None
    assert any(message in e.message for e in errors), errors


def test_from_import_of_a_package_then_a_refused_module() -> None:
    source = "from numpy import lib\n\ndef reward_function(params):\n    return lib.format\n"
    (error,) = check_source(source)
    assert "module 'numpy.lib.format'" in error.message and error.line == 4


ALLOWED = (
    "    match params:\n"
    "        case {'speed': s, 'progress': p} if s > 0:\n"
    "            label = 'speed {0:.2f} {1[0]} {x}'.format(s, [p], x=math.pi)\n"
    "            return float(np.clip(s, 0, 4)) if label else 0.0\n"
    "        case _:\n"
    "            return 0.0\n"
)


def test_ordinary_code_still_passes_and_runs() -> None:
    assert check_source(HEAD + ALLOWED) == []
    hb = memoryview(bytearray(32)).cast("q")
    reward = RewardCallable(load_reward_function(HEAD + ALLOWED), hb)
    assert reward({"speed": 2.0, "progress": 5.0}) == 2.0


RUNTIME = {
    "dynamic_module_attribute": "    return getattr(np.lib, 'for' + 'mat')\n",
    "dynamic_format_method": "    return getattr('{0.' + '__class__}', 'for' + 'mat')(params)\n",
    "dynamic_private_name": "    return getattr(math, '_' + 'x')\n",
    "module_walk": "    for name in dir(np.lib):\n        getattr(np.lib, name)\n    return 1.0\n",
    "patch_a_library": "    np.sqrt = abs\n    return 1.0\n",
}


@pytest.mark.parametrize("body", RUNTIME.values(), ids=list(RUNTIME))
def test_refused_at_run_time(body: str) -> None:
    source = HEAD + body
    assert check_source(source) == []  # only the run-time guard can see these
    hb = memoryview(bytearray(32)).cast("q")
    reward = RewardCallable(load_reward_function(source), hb)
    with pytest.raises(RewardFunctionError) as caught:
        reward({"speed": 1.0})
    message = caught.value.error.message
    assert "AttributeError" in message
    assert any(w in message for w in ("not allowed", "cannot be changed", "literal only"))


def test_allowed_submodules_are_reached_through_the_guard() -> None:
    source = (
        "import numpy.linalg\nimport scipy.spatial as sp\nfrom shapely.geometry import Point\n"
        "import numpy as np\n\ndef reward_function(params):\n"
        "    d = sp.distance.euclidean((0, 0), (3, 4))\n"
        "    return float(np.linalg.norm([d, 0]) + Point(0, 0).x + numpy.linalg.norm([0]))\n"
    )
    assert check_source(source) == []
    hb = memoryview(bytearray(32)).cast("q")
    assert RewardCallable(load_reward_function(source), hb)({}) == 5.0
