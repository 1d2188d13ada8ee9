"""Errors of the reward sandbox: what the user sees, and what the caller catches."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal

ErrorType = Literal["SYNTAX_ERROR", "IMPORT_ERROR", "TEST_FAILURE"]
ERROR_TYPES: tuple[ErrorType, ...] = ("SYNTAX_ERROR", "IMPORT_ERROR", "TEST_FAILURE")

#: Name the user's source is compiled under: tracebacks are filtered to frames of this file.
USER_FILENAME = "reward_function.py"


#: An absolute path to a file of code: ours, the interpreter's or a library's.
_CODE_PATH = re.compile(
    r"(?<![\w.])(?:/[^\s/:'\"()<>,]+)+/([^\s/:'\"()<>,]+\.(?:py|pyc|pyi|pyx|so))\b"
)


def hide_paths(text: str) -> str:
    """``text`` with each path of a code file cut to the file's name
    (``/srv/racecraft/training/sandbox/oneshot.py:58`` -> ``oneshot.py:58``): messages say
    what happened, not where the server keeps its code."""
    return _CODE_PATH.sub(r"\1", text)


@dataclass(frozen=True)
class RewardError:
    """One problem with a reward function, in DeepRacer's error format.

    ``line`` and ``column`` are 1-based positions in the user's source, or None when the
    problem has no place in it (a timeout, a crashed sandbox).
    """

    type: ErrorType
    message: str
    line: int | None = None
    column: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; ``lineNumber`` repeats ``line`` as DeepRacer-on-AWS spells it."""
        return {
            "type": self.type,
            "message": self.message,
            "line": self.line,
            "lineNumber": self.line,
            "column": self.column,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RewardError:
        """Rebuild from :meth:`to_dict` output, coercing untrusted fields (it may come from
        the sandboxed child)."""
        kind = data.get("type")
        if kind not in ERROR_TYPES:
            kind = "TEST_FAILURE"
        line = data.get("line")
        column = data.get("column")
        return cls(
            type=kind,
            message=hide_paths(str(data.get("message", ""))[:2000]),
            line=line if type(line) is int else None,
            column=column if type(column) is int else None,
        )


class SandboxError(Exception):
    """Base of everything the parent side raises about a sandboxed process; its message never
    holds a path of the server's code (:func:`hide_paths`)."""

    def __init__(self, message: object = "", *args: object) -> None:
        super().__init__(hide_paths(str(message)), *args)


class SandboxStartError(SandboxError):
    """The sandbox process could not be started or did not become ready."""


class SandboxUnavailable(SandboxStartError):
    """This machine cannot give the sandbox a protection it needs, so no user code was run.

    The message is for the operator: what is missing and which kernel feature or container
    setting provides it. ``missing`` names the :mod:`training.sandbox.requirements`.
    """

    def __init__(self, message: str, missing: tuple[str, ...]) -> None:
        super().__init__(message)
        self.missing = missing


class SandboxCrashed(SandboxError):
    """The sandbox process died: killed by a limit, a signal, or its own doing.

    ``message`` is in plain words for the user ("exceeded its 1.0 s limit per call", ...).
    """


class SandboxTimeout(SandboxCrashed):
    """A call overran its wall-clock limit, or no message came before the deadline."""


class SandboxProtocolError(SandboxCrashed):
    """The child sent something that is not a valid message (it was killed)."""


class RewardFunctionError(SandboxError):
    """The reward function itself failed (exception, bad return value, compile error).

    Raised in the child by the guarded reward callable, and re-raised in the parent with the
    same :class:`RewardError`.
    """

    def __init__(self, error: RewardError, step: int | None = None) -> None:
        super().__init__(error.message)
        self.error = error
        self.step = step
