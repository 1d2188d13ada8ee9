"""The rules of the static check, node by node (:class:`Checker`), run by
:func:`training.sandbox.static.check_source`: refused imports, names, attributes, format
fields and class machinery. One list of what is refused lives in :mod:`~training.sandbox.policy`.
"""

from __future__ import annotations

import ast
import string
from _string import formatter_field_name_split  # the parser str.format itself uses
from collections.abc import Iterator

from training.sandbox.errors import RewardError
from training.sandbox.policy import (
    ALLOWED_DUNDER_METHODS,
    ALLOWED_DUNDER_NAMES,
    ALLOWED_MODULES,
    ATTRIBUTE_FUNCTIONS,
    FORBIDDEN_NAMES,
    NO_METACLASS,
    NO_TYPE_CALL,
    REFUSED_SUBMODULES,
    STAR_IMPORT_MODULES,
    attribute_refused,
    is_dunder,
    module_refused,
    special_method_refused,
)

#: Levels of nested format specs read (``"{:{:...}}"``). ``str.format`` evaluates one level
#: (``"{0:{1}}"``) and raises "Max string recursion exceeded" below it: deeper fields are never
#: read at run time, and reading them here would cost time quadratic in the source's length.
MAX_FORMAT_NESTING = 4


def at(node: ast.AST, kind: str, message: str) -> RewardError:
    col = getattr(node, "col_offset", None)
    return RewardError(
        kind, message, getattr(node, "lineno", None), None if col is None else col + 1
    )  # type: ignore[arg-type]


def format_attributes(template: str) -> Iterator[str]:
    """Attribute names a ``str.format`` template reads (``"{0.__class__}"`` -> ``__class__``),
    nested format specs included (down to :data:`MAX_FORMAT_NESTING` levels); nothing for
    text that is not a valid template."""
    todo = [(template, 0)]
    while todo:
        text, level = todo.pop()
        try:
            parsed = list(string.Formatter().parse(text))
        except ValueError:
            continue
        for _, field, spec, _ in parsed:
            if field:
                try:
                    _, rest = formatter_field_name_split(field)
                    yield from (str(key) for is_attr, key in rest if is_attr)
                except ValueError:
                    pass
            if spec and level < MAX_FORMAT_NESTING:
                todo.append((spec, level + 1))


def _literal(node: ast.AST) -> bool:
    """A string literal (``node.value`` is then a str)."""
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def _is_type(node: ast.AST) -> bool:
    return isinstance(node, ast.Name) and node.id == "type"


def _starred(args: list[ast.expr]) -> bool:
    return any(isinstance(a, ast.Starred) for a in args)


def _refused_submodule(dotted: str) -> bool:
    return any(dotted == m or dotted.startswith(m + ".") for m in REFUSED_SUBMODULES)


def _allowed_list() -> str:
    return ", ".join(sorted(ALLOWED_MODULES))


class Checker:
    """Refused imports, names and attribute access, however spelled: ``a.b``, the getattr
    family with a literal name, ``match`` class and mapping patterns, ``str.format`` fields,
    and refused modules reached as attributes of allowed ones (``np.lib.format``); refused
    class machinery (metaclasses, special methods that change lookups, ``type(n, b, d)``).

    The tree is walked with a stack, not recursion: a deep source gets an answer, never a
    RecursionError. ``visit_<Node>`` methods see each node before its children, as
    ast.NodeVisitor's would.
    """

    def __init__(self) -> None:
        self.errors: list[RewardError] = []
        self.modules: dict[str, str] = {}  # local name -> module it was imported as

    def run(self, tree: ast.AST, max_depth: int) -> tuple[int | None, int | None] | None:
        """Check every node down to ``max_depth`` levels; the place (line, 1-based column)
        of the first node deeper than that, where the walk stopped, or None."""
        stack: list[tuple[ast.AST, int, int | None]] = [(tree, 0, None)]
        while stack:
            node, depth, line = stack.pop()
            line = getattr(node, "lineno", line)
            if depth > max_depth:
                col = getattr(node, "col_offset", None)
                return line, None if col is None else col + 1
            visit = getattr(self, "visit_" + type(node).__name__, None)
            if visit is not None:
                visit(node)
            children = list(ast.iter_child_nodes(node))
            stack.extend((child, depth + 1, line) for child in reversed(children))
        return None

    def _refuse_attr(
        self, node: ast.AST, name: str, how: str = "attribute", where: str = ""
    ) -> None:
        message = f"access to {how} '{name}'{where} is not allowed"
        self.errors.append(at(node, "SYNTAX_ERROR", message))

    def _check_name(self, node: ast.AST, name: str | None) -> None:
        if name and (name in FORBIDDEN_NAMES or is_dunder(name)):
            self.errors.append(at(node, "SYNTAX_ERROR", f"use of '{name}' is not allowed"))

    def _refuse_import(self, node: ast.AST, name: str) -> None:
        self.errors.append(
            at(
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

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        module = node.module or ""
        if node.level or module_refused(module):
            self._refuse_import(node, "." * node.level + module)
            return
        for alias in node.names:
            if alias.name == "*":
                if module not in STAR_IMPORT_MODULES:
                    self.errors.append(
                        at(node, "IMPORT_ERROR", f"'from {module} import *' is not allowed")
                    )
            elif attribute_refused(alias.name) or module_refused(f"{module}.{alias.name}"):
                self._refuse_import(node, f"{module}.{alias.name}")
            else:
                self.modules[alias.asname or alias.name] = f"{module}.{alias.name}"

    def visit_Name(self, node: ast.Name) -> None:
        name = node.id
        if name == "__import__" or name == "importlib":
            self.errors.append(at(node, "IMPORT_ERROR", f"'{name}' is not allowed"))
        elif name in FORBIDDEN_NAMES or (is_dunder(name) and name not in ALLOWED_DUNDER_NAMES):
            self.errors.append(at(node, "SYNTAX_ERROR", f"use of '{name}' is not allowed"))

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

    def visit_Call(self, node: ast.Call) -> None:
        func = node.func
        if isinstance(func, ast.Name) and func.id in ATTRIBUTE_FUNCTIONS and len(node.args) > 1:
            name = node.args[1]
            if _literal(name) and attribute_refused(name.value):
                self._refuse_attr(name, name.value)
        if _is_type(func) and (len(node.args) != 1 or node.keywords or _starred(node.args)):
            self.errors.append(at(node, "SYNTAX_ERROR", NO_TYPE_CALL))
        formats = isinstance(func, ast.Attribute) and func.attr in ("format", "format_map")
        if formats and not _literal(func.value):
            self.errors.append(
                at(func, "SYNTAX_ERROR", f"'.{func.attr}' is allowed on a string literal only")
            )

    def visit_Constant(self, node: ast.Constant) -> None:
        if isinstance(node.value, str) and "{" in node.value:
            for name in format_attributes(node.value):
                if attribute_refused(name):
                    self._refuse_attr(node, name, where=" (in a format string)")

    def visit_MatchClass(self, node: ast.MatchClass) -> None:
        for name in node.kwd_attrs:  # case C(attr=...) reads C's attribute
            if attribute_refused(name):
                self._refuse_attr(node, name, where=" (in a class pattern)")

    def visit_MatchMapping(self, node: ast.MatchMapping) -> None:
        for key in node.keys:
            if _literal(key) and is_dunder(key.value):
                self._refuse_attr(key, key.value, "key", " (in a mapping pattern)")
        self._check_name(node, node.rest)

    def visit_MatchAs(self, node: ast.MatchAs) -> None:
        self._check_name(node, node.name)

    def visit_MatchStar(self, node: ast.MatchStar) -> None:
        self._check_name(node, node.name)

    def visit_FunctionDef(self, node: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
        self._check_definition(node, node.name)

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_ClassDef(self, node: ast.ClassDef) -> None:
        self._check_definition(node, node.name)
        for keyword in node.keywords:
            shown = f"{keyword.arg}=" if keyword.arg else "**"
            self.errors.append(
                at(keyword, "SYNTAX_ERROR", f"class keywords ('{shown}') are not allowed: "
                    "a reward function's classes take no metaclass or class arguments")
            )  # fmt: skip
        for base in node.bases:
            if _is_type(base) or (isinstance(base, ast.Call) and _is_type(base.func)):
                self.errors.append(at(base, "SYNTAX_ERROR", NO_METACLASS))

    def _check_definition(self, node: ast.AST, name: str) -> None:
        """``def __name__`` / ``class __name__``: only harmless special methods."""
        if is_dunder(name) and name not in ALLOWED_DUNDER_METHODS:
            self.errors.append(at(node, "SYNTAX_ERROR", special_method_refused(name)))

    def _check_bound(self, node: ast.AST, name: str | None) -> None:
        """A name bound without an ast.Name (a parameter, ``as`` of an import or except)."""
        if name and is_dunder(name) and name not in ALLOWED_DUNDER_NAMES:
            self.errors.append(at(node, "SYNTAX_ERROR", f"use of '{name}' is not allowed"))

    def visit_arg(self, node: ast.arg) -> None:
        self._check_bound(node, node.arg)

    def visit_alias(self, node: ast.alias) -> None:
        self._check_bound(node, node.asname)

    def visit_ExceptHandler(self, node: ast.ExceptHandler) -> None:
        self._check_bound(node, node.name)

    def visit_Global(self, node: ast.Global) -> None:
        self._check_declared(node, node.names)

    def visit_Nonlocal(self, node: ast.Nonlocal) -> None:
        self._check_declared(node, node.names)

    def _check_declared(self, node: ast.AST, names: list[str]) -> None:
        for name in names:
            self._check_name(node, name)
