"""Python-level guard inside the sandbox child: restricted builtins and imports, loading the
user's module, and the per-call wrapper around ``reward_function``.

This layer gives good error messages and stops the obvious; it is not the boundary (the OS
layers in :mod:`training.sandbox.lockdown` are). It runs only in the child.
"""

from __future__ import annotations

import builtins
import dis
import io
import sys
import time
import traceback
import types
import warnings
from collections.abc import Callable
from typing import Any

from training.sandbox.classes import GuardedType, guarded_build_class, is_metaclass
from training.sandbox.errors import USER_FILENAME, RewardError, RewardFunctionError, hide_paths
from training.sandbox.policy import (
    ALLOWED_MODULES,
    FORBIDDEN_NAMES,
    REFUSED_SUBMODULES,
    attribute_refused,
    module_refused,
)
from training.sandbox.static import BEYOND_PYTHON, FUNCTION_NAME, check_source, too_deep

MAX_REWARD = 1e5
_monotonic_ns = time.monotonic_ns


class BoundedOutput(io.TextIOBase):
    """A text sink that keeps the first ``limit`` characters and counts the rest (print floods
    cost CPU time, never memory or a blocked pipe)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.parts: list[str] = []
        self.kept = 0
        self.dropped = 0

    def writable(self) -> bool:
        return True

    def write(self, s: str) -> int:
        n = len(s)
        room = self.limit - self.kept
        if room > 0:
            piece = s[:room]
            self.parts.append(piece)
            self.kept += len(piece)
        self.dropped += max(0, n - max(room, 0))
        return n

    def take(self) -> str:
        text = hide_paths("".join(self.parts))
        if self.dropped:
            text += f"\n[... {self.dropped} more characters of output dropped]\n"
        self.parts, self.kept, self.dropped = [], 0, 0
        return text


def _refuse(kind: str, message: str) -> RewardFunctionError:
    return RewardFunctionError(RewardError(kind, message))  # type: ignore[arg-type]


class ModuleProxy:
    """What user code gets for an allowed module: attribute reads are checked like ``a.b``
    in the source, and a module reached as an attribute (``np.lib.format``, a library's own
    ``os`` or ``pickle``) must itself be allowed, so a refused module is refused however it
    is reached. Writes are refused (user code cannot patch a library for the next car)."""

    __slots__ = ("_module",)

    def __init__(self, module: types.ModuleType) -> None:
        object.__setattr__(self, "_module", module)

    def __getattr__(self, name: str) -> Any:
        _check_attr(name)
        value = getattr(object.__getattribute__(self, "_module"), name)
        return _exposed(value)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("modules cannot be changed")

    def __delattr__(self, name: str) -> None:
        raise AttributeError("modules cannot be changed")

    def __dir__(self) -> list[str]:
        return [n for n in dir(object.__getattribute__(self, "_module")) if n[0] != "_"]

    def __repr__(self) -> str:
        return f"<module {object.__getattribute__(self, '_module').__name__!r}>"


def _exposed(value: Any) -> Any:
    """``value`` as user code may see it: modules only when allowed, and behind a proxy; a
    metaclass (``type`` itself included) as the guarded ``type``."""
    if is_metaclass(value):
        return GuardedType
    if isinstance(value, types.ModuleType):
        if module_refused(value.__name__):
            raise AttributeError(f"access to module '{value.__name__}' is not allowed")
        return ModuleProxy(value)
    return value


#: The instruction an ``import`` statement runs; ``__import__`` called while the caller's frame
#: stands on any other instruction was called by C code (or directly), never by a statement.
_IMPORT_NAME = dis.opmap["IMPORT_NAME"]


def _import_statement(frame: types.FrameType) -> bool:
    """True when ``frame`` stands on an ``import``/``from ... import`` statement."""
    code = frame.f_code.co_code  # the unspecialised bytecode; f_lasti is a byte offset in it
    lasti = frame.f_lasti
    return 0 <= lasti < len(code) and code[lasti] == _IMPORT_NAME


def _library_may_load(name: str) -> bool:
    """What a library's own import may load: a module already loaded (nothing runs), or one
    of an allowed library's, private ones included, except its refused submodules."""
    if name in sys.modules:
        return True
    return name.split(".")[0] in ALLOWED_MODULES and not any(
        name == bad or name.startswith(bad + ".") for bad in REFUSED_SUBMODULES
    )


def _restricted_import(name: str, globals=None, locals=None, fromlist=(), level=0):  # noqa: ANN001,ANN202
    """``__import__`` of the user's builtins. Two callers reach it:

    - the user's ``import`` statements (the caller's frame stands on IMPORT_NAME): checked
      against the allow-list, and the module comes back behind a :class:`ModuleProxy`;
    - C code a library runs on the user's behalf: ``PyImport_Import`` looks ``__import__`` up
      in the builtins of the calling Python frame, the user's, and passes the user's globals
      (numpy imports ``numpy._core._methods`` the first time ``arr.mean()`` runs). The
      module is loaded if :func:`_library_may_load`, and None comes back: ``PyImport_Import``
      drops what ``__import__`` returns and reads ``sys.modules``, so a user who somehow
      called this function directly would get nothing from it.

    Which one is asked is read from the caller's instruction, not from ``globals`` (the user's
    in both cases) nor from any argument the caller chooses.
    """
    if not _import_statement(sys._getframe(1)):
        if level or fromlist or type(name) is not str or not _library_may_load(name):
            raise ImportError(f"import of '{name}' is not allowed")
        builtins.__import__(name, None, None, (), 0)
        return None
    if level or module_refused(name):
        raise ImportError(f"import of '{name}' is not allowed")
    for item in fromlist or ():
        if item == "*" or attribute_refused(item) or module_refused(f"{name}.{item}"):
            if item == "*" and name.split(".")[0] in ("math", "random"):
                continue
            raise ImportError(f"import of '{name}.{item}' is not allowed")
    module = builtins.__import__(name, globals, locals, fromlist, 0)
    if fromlist and "*" in fromlist:  # the names are copied out of the module by the caller
        return module
    return ModuleProxy(module)


def _check_attr(name: object) -> None:
    if not isinstance(name, str) or attribute_refused(name):
        raise AttributeError(f"access to attribute '{name}' is not allowed")


def _getattr(obj: object, name: str, *default: object) -> object:
    _check_attr(name)
    if isinstance(obj, str) and name in ("format", "format_map"):
        # A template built at run time would escape the static check of its fields.
        raise AttributeError(f"'{name}' is allowed on a string literal only")
    return _exposed(getattr(obj, name, *default))


def _hasattr(obj: object, name: str) -> bool:
    _check_attr(name)
    return hasattr(obj, name)


def _setattr(obj: object, name: str, value: object) -> None:
    _check_attr(name)
    setattr(obj, name, value)


def _delattr(obj: object, name: str) -> None:
    _check_attr(name)
    delattr(obj, name)


def restricted_builtins() -> dict[str, Any]:
    """Builtins for user code: no open/eval/exec/compile/input/..., guarded getattr family,
    and an ``__import__`` that serves only the allowed modules."""
    allowed = {
        k: v
        for k, v in vars(builtins).items()
        if k not in FORBIDDEN_NAMES and not k.startswith("_")
    }
    allowed.update(
        __import__=_restricted_import,
        __build_class__=guarded_build_class,
        __name__="builtins",
        type=GuardedType,
        getattr=_getattr,
        hasattr=_hasattr,
        setattr=_setattr,
        delattr=_delattr,
    )
    return allowed


def user_error(exc: BaseException, step: int | None, phase: str) -> RewardError:
    """TEST_FAILURE for an exception raised by user code, placed at the last frame of the
    user's file (line and 1-based column)."""
    line = column = None
    try:
        for frame in traceback.extract_tb(exc.__traceback__):
            if frame.filename == USER_FILENAME:
                line = frame.lineno
                column = frame.colno + 1 if frame.colno is not None else None
    except Exception:  # noqa: BLE001 - a hostile traceback must not break reporting
        pass
    try:
        detail = hide_paths(str(exc)[:500])
    except BaseException:  # noqa: BLE001
        detail = "<unprintable>"
    name = type(exc).__name__ if type(exc).__module__ == "builtins" else "exception"
    where = f" at step {step}" if step is not None else ""
    text = f"{phase} raised {name}{where}: {detail}" if detail else f"{phase} raised {name}{where}"
    return RewardError("TEST_FAILURE", text, line, column)


def load_reward_function(
    source: str, *, python_guards: bool = True
) -> Callable[[dict[str, Any]], Any]:
    """Compile and run the user's module; return its ``reward_function``.

    Raises RewardFunctionError for static errors or an exception at module level.
    ``python_guards=False`` skips the static check and restricted builtins; only tests use it,
    to show that the OS layers hold on their own.
    """
    if python_guards:
        errors = check_source(source)
        if errors:
            raise RewardFunctionError(errors[0])
    try:
        code = compile(source, USER_FILENAME, "exec", dont_inherit=True)
    except (SyntaxError, ValueError) as exc:
        line = getattr(exc, "lineno", None)
        raise RewardFunctionError(RewardError("SYNTAX_ERROR", str(exc), line)) from None
    except (RecursionError, MemoryError):  # the compiler's own limits on nesting
        raise RewardFunctionError(too_deep(BEYOND_PYTHON)) from None
    module = types.ModuleType("reward_function")
    module.__file__ = USER_FILENAME
    if python_guards:
        module.__dict__["__builtins__"] = restricted_builtins()
    try:
        exec(code, module.__dict__)
    except BaseException as exc:  # noqa: BLE001 - SystemExit & co. from user code included
        err = user_error(exc, None, "loading the module")
        if isinstance(exc, ImportError):
            err = RewardError("IMPORT_ERROR", str(exc)[:500], err.line, err.column)
        raise RewardFunctionError(err) from None
    fn = module.__dict__.get(FUNCTION_NAME)
    if not callable(fn):
        raise RewardFunctionError(RewardError("SYNTAX_ERROR", f"no function '{FUNCTION_NAME}'"))
    return fn


def copy_params(params: dict[str, Any]) -> dict[str, Any]:
    """A copy the user may mutate freely: new dict, new lists (elements are immutable tuples,
    numbers, bools; inner lists are turned into tuples)."""
    out = {}
    for k, v in params.items():
        if type(v) is list:
            v = [tuple(e) for e in v] if v and type(v[0]) is list else v.copy()
        out[k] = v
    return out


def _bad_value(value: object, step: int) -> RewardError:
    t = type(value)
    shown = f"an object of type {t.__name__}"
    if t in (float, int, bool, str, type(None)) or t.__module__ == "numpy":
        try:
            shown = repr(value)
            shown = shown if len(shown) <= 60 else shown[:60] + "..."
        except ValueError:  # an int too long to print
            shown = "a number too large"
    return RewardError(
        "TEST_FAILURE",
        f"reward_function returned {shown} at step {step}; it must return a finite number "
        f"in [-{MAX_REWARD:.0f}, {MAX_REWARD:.0f}]",
    )


class RewardCallable:
    """``reward(params) -> float``: the guarded call used on every simulation step.

    Writes the step number and call start time into ``heartbeat`` (shared with the parent's
    watchdog, which kills the process when a call overruns), passes a copy of ``params``,
    checks the result, and turns any failure into RewardFunctionError with a TEST_FAILURE.
    """

    def __init__(self, fn: Callable[[dict[str, Any]], Any], heartbeat: memoryview) -> None:
        import numpy

        self._fn = fn
        self._hb = heartbeat
        self._np_number = (numpy.integer, numpy.floating)
        self.step = 0

    def __call__(self, params: dict[str, Any]) -> float:
        self.step += 1
        hb = self._hb
        hb[0] = self.step
        hb[1] = _monotonic_ns()
        try:
            value = self._fn(copy_params(params))
            t = type(value)
            if t is float:
                result = value
            elif t is int or t is bool or isinstance(value, self._np_number):
                try:
                    result = float(value)
                except OverflowError:
                    raise RewardFunctionError(_bad_value(value, self.step), self.step) from None
            else:
                raise RewardFunctionError(_bad_value(value, self.step), self.step)
            if not -MAX_REWARD <= result <= MAX_REWARD:  # NaN fails both comparisons
                raise RewardFunctionError(_bad_value(value, self.step), self.step)
        except RewardFunctionError:
            hb[1] = 0
            raise
        except BaseException as exc:  # noqa: BLE001 - SystemExit, KeyboardInterrupt too
            err = user_error(exc, self.step, "reward_function")
            hb[1] = 0
            raise RewardFunctionError(err, self.step) from None
        hb[1] = 0
        return result


def show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: object = None,
    line: str | None = None,
) -> None:
    """A warning as the user needs it: ``reward_function.py:3: RuntimeWarning: ...`` for one
    in their code, the category and message alone for one raised in a library or in ours
    (no server paths, no source lines of our code)."""
    where = f"{USER_FILENAME}:{lineno}: " if filename == USER_FILENAME else ""
    sys.stderr.write(f"{where}{category.__name__}: {hide_paths(str(message))}\n")


def install_output_capture(limit: int) -> BoundedOutput:
    """Send print() and warnings to a :class:`BoundedOutput` of ``limit`` characters."""
    sink = BoundedOutput(limit)
    sys.stdout = sys.stderr = sink  # type: ignore[assignment]
    warnings.showwarning = show_warning
    return sink
