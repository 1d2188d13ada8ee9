"""Static checks of a reward function's source: syntax, imports, refused names, signature.

Pure Python (``ast``), no process: the first, cheap gate of validation, and a second line run
again inside the sandbox before the source is executed. The OS layer does not rely on it.
"""

from __future__ import annotations

import ast
import string
import warnings
from _string import formatter_field_name_split  # the parser str.format itself uses
from collections.abc import Iterator

from training.sandbox.errors import USER_FILENAME, RewardError
from training.sandbox.policy import (
    ALLOWED_DUNDER_NAMES,
    ALLOWED_MODULES,
    ATTRIBUTE_FUNCTIONS,
    FORBIDDEN_NAMES,
    REFUSED_SUBMODULES,
    STAR_IMPORT_MODULES,
    attribute_refused,
    is_dunder,
    module_refused,
)

#: Maximum source length in characters [DeepRacer-on-AWS RewardFunctionCode].
MAX_SOURCE_CHARS = 140_000
FUNCTION_NAME = "reward_function"


def parse_source(source: str) -> tuple[ast.Module | None, list[RewardError]]:
    """Parse ``source``; return the tree, or None and one SYNTAX_ERROR."""
    if len(source) > MAX_SOURCE_CHARS:
        msg = f"the source has {len(source):,} characters; at most {MAX_SOURCE_CHARS:,} allowed"
        return None, [RewardError("SYNTAX_ERROR", msg)]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tree = ast.parse(source, filename=USER_FILENAME)
    except SyntaxError as exc:
        column = exc.offset if exc.offset and exc.offset > 0 else None
        return None, [RewardError("SYNTAX_ERROR", f"{exc.msg}", exc.lineno, column)]
    except (ValueError, RecursionError, MemoryError) as exc:
        return None, [RewardError("SYNTAX_ERROR", f"the source cannot be parsed: {exc}")]
    return tree, []


def _at(node: ast.AST, kind: str, message: str) -> RewardError:
    col = getattr(node, "col_offset", None)
    return RewardError(
        kind, message, getattr(node, "lineno", None), None if col is None else col + 1
    )  # type: ignore[arg-type]


def format_attributes(template: str) -> Iterator[str]:
    """Attribute names a ``str.format`` template reads (``"{0.__class__}"`` -> ``__class__``),
    nested format specs included; nothing for text that is not a valid template."""
    try:
        parsed = list(string.Formatter().parse(template))
    except ValueError:
        return
    for _, field, spec, _ in parsed:
        if field:
            try:
                _, rest = formatter_field_name_split(field)
                yield from (str(key) for is_attr, key in rest if is_attr)
            except ValueError:
                pass
        if spec:
            yield from format_attributes(spec)


def _literal(node: ast.AST) -> bool:
    """A string literal (``node.value`` is then a str)."""
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def _refused_submodule(dotted: str) -> bool:
    return any(dotted == m or dotted.startswith(m + ".") for m in REFUSED_SUBMODULES)


def _allowed_list() -> str:
    return ", ".join(sorted(ALLOWED_MODULES))


class _Checker(ast.NodeVisitor):
    """Refused imports, names and attribute access, however spelled: ``a.b``, the getattr
    family with a literal name, ``match`` class and mapping patterns, ``str.format`` fields,
    and refused modules reached as attributes of allowed ones (``np.lib.format``)."""

    def __init__(self) -> None:
        self.errors: list[RewardError] = []
        self.modules: dict[str, str] = {}  # local name -> module it was imported as

    def _refuse_attr(
        self, node: ast.AST, name: str, how: str = "attribute", where: str = ""
    ) -> None:
        message = f"access to {how} '{name}'{where} is not allowed"
        self.errors.append(_at(node, "SYNTAX_ERROR", message))

    def _check_name(self, node: ast.AST, name: str | None) -> None:
        if name and (name in FORBIDDEN_NAMES or is_dunder(name)):
            self.errors.append(_at(node, "SYNTAX_ERROR", f"use of '{name}' is not allowed"))

    def _refuse_import(self, node: ast.AST, name: str) -> None:
        self.errors.append(
            _at(
                node,
                "IMPORT_ERROR",
                f"import of '{name}' is not allowed (allowed: {_allowed_list()})",
            )
        )

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            if module_refused(alias.name):
                self._refuse_import(node, alias.name)
            elif alias.asname:
                self.modules[alias.asname] = alias.name
            else:
                root = alias.name.split(".")[0]
                self.modules[root] = root
        self.generic_visit(node)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        module = node.module or ""
        if node.level or module_refused(module):
            self._refuse_import(node, "." * node.level + module)
            return
        for alias in node.names:
            if alias.name == "*":
                if module not in STAR_IMPORT_MODULES:
                    self.errors.append(
                        _at(node, "IMPORT_ERROR", f"'from {module} import *' is not allowed")
                    )
            elif attribute_refused(alias.name) or module_refused(f"{module}.{alias.name}"):
                self._refuse_import(node, f"{module}.{alias.name}")
            else:
                self.modules[alias.asname or alias.name] = f"{module}.{alias.name}"
        self.generic_visit(node)

    def visit_Name(self, node: ast.Name) -> None:
        name = node.id
        if name == "__import__" or name == "importlib":
            self.errors.append(_at(node, "IMPORT_ERROR", f"'{name}' is not allowed"))
        elif name in FORBIDDEN_NAMES or (is_dunder(name) and name not in ALLOWED_DUNDER_NAMES):
            self.errors.append(_at(node, "SYNTAX_ERROR", f"use of '{name}' is not allowed"))

    def _dotted(self, node: ast.Attribute) -> str | None:
        """``numpy.lib.format`` for ``np.lib.format`` when ``np`` names an imported module."""
        parts = [node.attr]
        value = node.value
        while isinstance(value, ast.Attribute):
            parts.append(value.attr)
            value = value.value
        if not isinstance(value, ast.Name) or value.id not in self.modules:
            return None
        return ".".join([self.modules[value.id], *reversed(parts)])

    def visit_Attribute(self, node: ast.Attribute) -> None:
        dotted = self._dotted(node)
        if dotted and not attribute_refused(node.attr) and _refused_submodule(dotted):
            self._refuse_attr(node, dotted, "module")
        if attribute_refused(node.attr):
            # Point at the attribute's name, not at the start of the whole expression.
            col = (node.end_col_offset or 0) - len(node.attr)
            self.errors.append(
                RewardError(
                    "SYNTAX_ERROR",
                    f"access to attribute '{node.attr}' is not allowed",
                    node.end_lineno,
                    col + 1,
                )
            )
        self.generic_visit(node)

    def visit_Call(self, node: ast.Call) -> None:
        func = node.func
        if isinstance(func, ast.Name) and func.id in ATTRIBUTE_FUNCTIONS and len(node.args) > 1:
            name = node.args[1]
            if _literal(name) and attribute_refused(name.value):
                self._refuse_attr(name, name.value)
        formats = isinstance(func, ast.Attribute) and func.attr in ("format", "format_map")
        if formats and not _literal(func.value):
            self.errors.append(
                _at(func, "SYNTAX_ERROR", f"'.{func.attr}' is allowed on a string literal only")
            )
        self.generic_visit(node)

    def visit_Constant(self, node: ast.Constant) -> None:
        if isinstance(node.value, str) and "{" in node.value:
            for name in format_attributes(node.value):
                if attribute_refused(name):
                    self._refuse_attr(node, name, where=" (in a format string)")

    def visit_MatchClass(self, node: ast.MatchClass) -> None:
        for name in node.kwd_attrs:  # case C(attr=...) reads C's attribute
            if attribute_refused(name):
                self._refuse_attr(node, name, where=" (in a class pattern)")
        self.generic_visit(node)

    def visit_MatchMapping(self, node: ast.MatchMapping) -> None:
        for key in node.keys:
            if _literal(key) and is_dunder(key.value):
                self._refuse_attr(key, key.value, "key", " (in a mapping pattern)")
        self._check_name(node, node.rest)
        self.generic_visit(node)

    def visit_MatchAs(self, node: ast.MatchAs) -> None:
        self._check_name(node, node.name)
        self.generic_visit(node)

    def visit_MatchStar(self, node: ast.MatchStar) -> None:
        self._check_name(node, node.name)

    def visit_Global(self, node: ast.Global) -> None:
        self._check_declared(node, node.names)

    def visit_Nonlocal(self, node: ast.Nonlocal) -> None:
        self._check_declared(node, node.names)

    def _check_declared(self, node: ast.AST, names: list[str]) -> None:
        for name in names:
            self._check_name(node, name)


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
        return [_at(fn, "SYNTAX_ERROR", f"'{FUNCTION_NAME}' must not be async")]
    a = fn.args
    count = len(a.posonlyargs) + len(a.args)
    if count != 1 or a.vararg or a.kwarg or a.kwonlyargs:
        return [
            _at(
                fn,
                "TEST_FAILURE",
                f"'{FUNCTION_NAME}' must take exactly one parameter (params)",
            )
        ]
    return []


def check_source(source: str) -> list[RewardError]:
    """All static errors of ``source`` (empty when it may run), in source order."""
    tree, errors = parse_source(source)
    if tree is None:
        return errors
    checker = _Checker()
    checker.visit(tree)
    errors = sorted(checker.errors, key=lambda e: (e.line or 0, e.column or 0))
    return errors + _check_signature(tree)
