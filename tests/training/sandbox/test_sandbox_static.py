"""Attribute access however it is spelled (match patterns, format strings, the getattr family)
is checked like ``a.b``; refused modules are refused when reached as attributes too."""

from __future__ import annotations

import pytest

from training.sandbox import RewardError, RewardFunctionError, check_source
from training.sandbox.guard import RewardCallable, load_reward_function
from training.sandbox.static import MAX_SOURCE_CHARS, SOURCE_TOO_LONG, source_too_long

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


# ------------------------------------------------------------------ class machinery (issue 22)
CLASS_REFUSED = {
    "metaclass_base": ("class M(type):\n    pass\n", 1, "may not derive from 'type'"),
    "metaclass_of_a_value": ("class M(type(1)):\n    pass\n", 1, "may not derive from 'type'"),
    "metaclass_keyword": (
        "class C(metaclass=abs):\n    pass\n",
        1,
        "class keywords ('metaclass=')",
    ),
    "class_keyword": ("class C(flavour=1):\n    pass\n", 1, "class keywords ('flavour=')"),
    "instancecheck": (
        "class C:\n    def __instancecheck__(self, o):\n        return True\n",
        2,
        "defining '__instancecheck__' is not allowed",
    ),
    "getattr_method": (
        "class C:\n    x = 1\n    def __getattr__(self, n):\n        return 1\n",
        3,
        "defining '__getattr__' is not allowed",
    ),
    "init_subclass": (
        "class C:\n    def __init_subclass__(cls):\n        pass\n",
        2,
        "defining '__init_subclass__'",
    ),
    "match_args": ("class C:\n    __match_args__ = ('x',)\n", 2, "use of '__match_args__'"),
    "type_three_args": ("C = type('C', (), {})\n", 1, "three arguments"),
    "type_starred": ("C = type(*('C', (), {}))\n", 1, "three arguments"),
    "type_keyword": ("C = type(object=1)\n", 1, "three arguments"),
    "dunder_parameter": ("def f(__builtins__):\n    pass\n", 1, "use of '__builtins__'"),
    "dunder_import_alias": ("import math as __loader__\n", 1, "use of '__loader__'"),
    "dunder_except_name": (
        "try:\n    pass\nexcept Exception as __spec__:\n    pass\n",
        3,
        "use of '__spec__'",
    ),
}


@pytest.mark.parametrize("code, line, message", CLASS_REFUSED.values(), ids=list(CLASS_REFUSED))
def test_class_machinery_is_refused_at_its_line(code: str, line: int, message: str) -> None:
    errors = check_source(code + "\ndef reward_function(params):\n    return 1.0\n")
    assert errors, code
    first = errors[0]
    assert first.type == "SYNTAX_ERROR" and (first.line, message in first.message) == (line, True)
    assert first.column is not None


def test_ordinary_classes_still_pass_and_run() -> None:
    source = (
        "import math\n\n"
        "class Vec:\n"
        "    def __init__(self, x, y):\n        self.x, self.y = x, y\n"
        "    def __add__(self, o):\n        return Vec(self.x + o.x, self.y + o.y)\n"
        "    def __sub__(self, o):\n        return Vec(self.x - o.x, self.y - o.y)\n"
        "    def __abs__(self):\n        return math.hypot(self.x, self.y)\n"
        "    def __eq__(self, o):\n        return (self.x, self.y) == (o.x, o.y)\n"
        "    def __hash__(self):\n        return hash((self.x, self.y))\n"
        "    def __iter__(self):\n        return iter((self.x, self.y))\n"
        "    def __repr__(self):\n        return f'Vec({self.x}, {self.y})'\n\n"
        "class Named(Vec):\n"
        "    def scaled(self, k):\n        return Named(self.x * k, self.y * k)\n\n"
        "def reward_function(params):\n"
        "    a, b = Named(3, 0).scaled(1), Vec(0, 4)\n"
        "    assert type(a) is Named and isinstance(Named, type) and type(type(a)) is type\n"
        "    return abs(a - b) if a + b == Vec(3, 4) else 0.0\n"
    )
    assert check_source(source) == []
    hb = memoryview(bytearray(32)).cast("q")
    assert RewardCallable(load_reward_function(source), hb)({}) == 5.0


# ------------------------------------------------------------------ deep sources (issue 22)
def _elif_table(branches: int) -> str:
    lines = ["def reward_function(params):", "    x = int(params['steps'])", "    if x == 0:"]
    lines.append("        return 0.5")
    for i in range(1, branches):
        lines += [f"    elif x == {i}:", f"        return {i / branches}"]
    return "\n".join([*lines, "    return 1.0", ""])


def test_a_500_branch_elif_table_passes_and_runs() -> None:
    source = _elif_table(500)
    assert check_source(source) == []
    hb = memoryview(bytearray(32)).cast("q")
    assert RewardCallable(load_reward_function(source), hb)({"steps": 250}) == 0.5


FN = "def reward_function(params):\n    return "
DEEP = {
    "long_sum": (FN + "1.0" + " + 1" * 5000 + "\n", None),
    "long_attribute_chain": (FN + "params" + ".get" * 5000 + "\n", None),
    "long_call_chain": (FN + "float" + "(1)" * 5000 + "\n", None),
    "long_unary_chain": (FN + "-" * 5000 + "1.0\n", None),
    "long_subscript_chain": (FN + "params" + "[0]" * 5000 + "\n", None),
    "nested_conditional": (FN + "1.0 if params else " * 2000 + "1.0\n", 2),
    "nested_lambdas": (FN + "(" + "lambda: " * 2000 + "1.0)\n", 2),
}


@pytest.mark.parametrize("source, line", DEEP.values(), ids=list(DEEP))
def test_a_source_too_deep_to_check_gets_one_clear_error(source: str, line: int | None) -> None:
    (error,) = check_source(source)
    assert error.type == "SYNTAX_ERROR"
    assert error.message.startswith("the reward function is nested too deeply to check: ")
    assert error.line == line
    with pytest.raises(RewardFunctionError) as caught:  # the sandbox's loader says the same
        load_reward_function(source)
    assert caught.value.error == error


NOT_TOO_DEEP = {
    "nested_brackets": FN + "float(len(" + "[" * 150 + "]" * 150 + "))\n",
    "nested_parentheses": FN + "(" * 150 + "1.0" + ")" * 150 + "\n",
    "long_boolean_chain": FN + "1.0" + " and 1.0" * 5000 + "\n",
    "long_comparison_chain": FN + "float(1" + " < 2" * 5000 + ")\n",
    "nested_format_specs": FN + "float(len('" + "{:" * 3000 + "}" * 3000 + "'))\n",
}


@pytest.mark.parametrize("source", NOT_TOO_DEEP.values(), ids=list(NOT_TOO_DEEP))
def test_deep_but_checkable_sources_pass_and_load(source: str) -> None:
    assert check_source(source) == []
    assert callable(load_reward_function(source))


def test_fields_in_nested_format_specs_are_still_read() -> None:
    source = FN + "'{0:{1:{2.__class__}}}'.format(1, 2, params)\n"
    (error,) = check_source(source)
    assert "'__class__' (in a format string)" in error.message


def test_the_compiler_giving_up_is_a_clear_error_too() -> None:
    """Without the static check (python_guards=False) compile() itself meets the nesting."""
    source = FN + "(" + "lambda: " * 20_000 + "1.0)\n"
    with pytest.raises(RewardFunctionError) as caught:
        load_reward_function(source, python_guards=False)
    assert caught.value.error.message.startswith("the reward function is nested too deeply")


def test_one_message_for_a_source_too_long() -> None:
    source = "def reward_function(p):\n    return 1.0\n" + "#" * MAX_SOURCE_CHARS
    assert source_too_long(source) == RewardError("SYNTAX_ERROR", SOURCE_TOO_LONG)
    assert source_too_long(source[:MAX_SOURCE_CHARS]) is None
    assert check_source(source) == [RewardError("SYNTAX_ERROR", SOURCE_TOO_LONG)]
    assert "140,000 characters" in SOURCE_TOO_LONG
