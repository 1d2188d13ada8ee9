"""Static checks of a reward function's source: syntax, imports, refused names, signature.

Pure Python (``ast``), no process: the first, cheap gate of validation, and a second line run
again inside the sandbox before the source is executed. The OS layer does not rely on it.
"""

from __future__ import annotations

import ast
import warnings

from training.sandbox.errors import USER_FILENAME, RewardError
from training.sandbox.static_rules import Checker, at, format_attributes

__all__ = [
    "BEYOND_PYTHON",
    "FUNCTION_NAME",
    "MAX_NESTING",
    "MAX_SOURCE_CHARS",
    "SOURCE_TOO_LONG",
    "TOO_DEEP",
    "check_source",
    "format_attributes",
    "parse_source",
    "source_too_long",
    "too_deep",
]

#: Maximum source length in characters [DeepRacer-on-AWS RewardFunctionCode].
MAX_SOURCE_CHARS = 140_000
#: The one message for a source over :data:`MAX_SOURCE_CHARS`, wherever it is refused (the
#: Validate button, the command line, saving, an imported archive: ``name: <message>``).
SOURCE_TOO_LONG = (
    f"longer than {MAX_SOURCE_CHARS:,} characters, the most a reward function may have"
)
#: Levels of nested blocks and expressions the check walks. Far more than a reward needs (a
#: 500-branch ``elif`` table is about 500 deep) and well below where Python's own compiler
#: gives up (about 3,000 at the default recursion limit), so what passes here compiles.
MAX_NESTING = 1_000
TOO_DEEP = "the reward function is nested too deeply to check"
FUNCTION_NAME = "reward_function"


def source_too_long(source: str) -> RewardError | None:
    """The error for a source longer than :data:`MAX_SOURCE_CHARS`, or None."""
    if len(source) > MAX_SOURCE_CHARS:
        return RewardError("SYNTAX_ERROR", SOURCE_TOO_LONG)
    return None


def too_deep(detail: str, line: int | None = None, column: int | None = None) -> RewardError:
    """``the reward function is nested too deeply to check: <detail>``, at its place when
    known."""
    return RewardError("SYNTAX_ERROR", f"{TOO_DEEP}: {detail}", line, column)


#: What Python's parser or compiler says of a source nested past its limits.
BEYOND_PYTHON = (
    "its blocks or expressions nest deeper than Python can parse; split long chains "
    "(a+b+c+..., a.b.c..., nested brackets) into steps with names"
)


def parse_source(source: str) -> tuple[ast.Module | None, list[RewardError]]:
    """Parse ``source``; return the tree, or None and one SYNTAX_ERROR."""
    if (long := source_too_long(source)) is not None:
        return None, [long]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tree = ast.parse(source, filename=USER_FILENAME)
    except SyntaxError as exc:
        column = exc.offset if exc.offset and exc.offset > 0 else None
        return None, [RewardError("SYNTAX_ERROR", f"{exc.msg}", exc.lineno, column)]
    except (RecursionError, MemoryError):  # the parser's own stack: nesting, not memory
        return None, [too_deep(BEYOND_PYTHON)]
    except ValueError as exc:
        return None, [RewardError("SYNTAX_ERROR", f"the source cannot be parsed: {exc}")]
    return tree, []


def _check_signature(tree: ast.Module) -> list[RewardError]:
    defs = [
        n
        for n in tree.body
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef) and n.name == FUNCTION_NAME
    ]
    if not defs:
        return [RewardError("SYNTAX_ERROR", f"no top-level function '{FUNCTION_NAME}(params)'")]
    fn = defs[-1]
    if isinstance(fn, ast.AsyncFunctionDef):
        return [at(fn, "SYNTAX_ERROR", f"'{FUNCTION_NAME}' must not be async")]
    a = fn.args
    count = len(a.posonlyargs) + len(a.args)
    if count != 1 or a.vararg or a.kwarg or a.kwonlyargs:
        return [
            at(
                fn,
                "TEST_FAILURE",
                f"'{FUNCTION_NAME}' must take exactly one parameter (params)",
            )
        ]
    return []


def check_source(source: str) -> list[RewardError]:
    """All static errors of ``source`` (empty when it may run), in source order.

    Never raises for any text: a source nested past what can be checked gets one
    :func:`too_deep` error, one over :data:`MAX_SOURCE_CHARS` the :data:`SOURCE_TOO_LONG` one.
    """
    tree, errors = parse_source(source)
    if tree is None:
        return errors
    checker = Checker()
    try:
        stopped = checker.run(tree, MAX_NESTING)
    except (RecursionError, MemoryError):  # not expected of the walk; still an answer
        return [too_deep(BEYOND_PYTHON)]
    if stopped is not None:
        levels = f"more than {MAX_NESTING:,} levels of blocks or expressions inside each other"
        return [too_deep(levels, *stopped)]
    errors = sorted(checker.errors, key=lambda e: (e.line or 0, e.column or 0))
    return errors + _check_signature(tree)
