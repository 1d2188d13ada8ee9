"""Validating a reward function before a model is created or a job starts.

``validate_reward_function(source, track)`` is the one service the console and the command
line share. Static checks first (length, syntax, imports, refused names, signature), then the
function is run in the sandbox on realistic params the simulator builds from the chosen track
for each situation (start line, mid-lap, near the finish, off track, reversed, with objects;
the first five have no objects), each under DeepRacer's 5 s limit.

Command line::

    python -m training.rewards.validation path/to/reward.py --track racecraft_oval

prints the result as JSON and exits 1 when there are errors (2 for a usage problem).
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import sys
from dataclasses import dataclass, field
from typing import Any

from racing.params import SCENARIOS, scenario_params
from racing.track import Track
from racing.tracks import TrackCatalog, UnknownTrackError
from training.sandbox import (
    VALIDATION_LIMITS,
    RewardError,
    SandboxLimits,
    SandboxUnavailable,
    check_source,
    evaluate_reward,
)

#: Situations the runtime checks cover, in the order they run.
SITUATIONS: tuple[str, ...] = tuple(SCENARIOS)


@dataclass
class ValidationResult:
    """Outcome of validation: ``ok`` when ``errors`` is empty. ``rewards`` maps each situation
    that ran cleanly to its reward; ``layers`` is the sandbox's isolation report; ``output``
    what the function printed (bounded); ``warnings`` says when it ran with weakened isolation
    (``RACECRAFT_ALLOW_WEAK_SANDBOX``)."""

    errors: list[RewardError]
    rewards: dict[str, float] = field(default_factory=dict)
    layers: dict[str, str] = field(default_factory=dict)
    output: str = ""
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "errors": [e.to_dict() for e in self.errors],
            "rewards": self.rewards,
            "layers": self.layers,
            "output": self.output,
            "warnings": self.warnings,
        }


def situation_params(track: Track, situations: tuple[str, ...] = SITUATIONS) -> list[dict]:
    """DeepRacer params for each situation on ``track``, built by the simulator."""
    return [scenario_params(track, name) for name in situations]


def _load_track(track: Track | str) -> Track:
    """A Track as given, or a built-in track by id (the console passes Track objects loaded
    from its own catalogue; the command line passes its own catalogue's track)."""
    return TrackCatalog().load(track) if isinstance(track, str) else track


def validate_reward_function(
    source: str,
    track: Track | str,
    *,
    situations: tuple[str, ...] = SITUATIONS,
    limits: SandboxLimits = VALIDATION_LIMITS,
) -> ValidationResult:
    """Validate ``source`` for ``track`` (a Track or a catalog id).

    Errors come back as RewardError with DeepRacer's types: SYNTAX_ERROR (syntax, refused
    names, length), IMPORT_ERROR (refused imports), TEST_FAILURE (runtime: exceptions with
    the line in the user's source, bad return values, time limits, a crashed sandbox, or a
    machine that cannot isolate reward code: then nothing ran and the one error says what the
    operator must provide). Raises UnknownTrackError for an unknown track id.
    """
    loaded = _load_track(track)
    errors = [_as_permission_error(e) for e in check_source(source)]
    if errors:
        return ValidationResult(errors)
    try:
        result = evaluate_reward(
            source, situation_params(loaded, situations), limits=limits, stop_after_timeout=True
        )
    except SandboxUnavailable as exc:
        return ValidationResult([RewardError("TEST_FAILURE", str(exc))])
    outcomes = result.outcomes
    rewards: dict[str, float] = {}
    failed: dict[tuple, list[str]] = {}  # one entry per distinct error, with its situations
    for name, outcome in zip(situations, outcomes, strict=False):  # none after a time-out
        if outcome.error is None:
            if outcome.value is not None:
                rewards[name] = outcome.value
            continue
        err = _placed(outcome.error, source)
        key = (err.type, _STEP.sub("", err.message), err.line, err.column)
        failed.setdefault(key, []).append(name)
    for (kind, message, line, column), names in failed.items():
        errors.append(
            RewardError(kind, _with_situations(message, names, situations, limits), line, column)
        )
    warnings = []
    if result.weak:
        warnings.append(
            "This reward function ran with weakened isolation (missing: "
            f"{', '.join(result.weak)}), because the operator set RACECRAFT_ALLOW_WEAK_SANDBOX."
        )
    return ValidationResult(errors, rewards, result.layers, result.output, warnings)


#: " at step 12" in the sandbox's messages: differs between situations, not between errors.
_STEP = re.compile(r" at step \d+")
_TIMEOUT = " s per call"  # the sandbox's words for a call that overran its limit


def _with_situations(
    message: str, names: list[str], situations: tuple[str, ...], limits: SandboxLimits
) -> str:
    """The error's message once, with the situations it happened in."""
    if _TIMEOUT in message:
        last = names[-1] == situations[-1]
        stopped = "" if last else " Validation stopped there: the later situations did not run."
        return (
            f"situation '{names[0]}': reward_function took longer than "
            f"{limits.per_call_seconds:g} s per call (a loop that never ends?).{stopped}"
        )
    if len(names) == 1:
        return f"situation '{names[0]}': {message}"
    if len(names) == len(situations) and len(names) > 1:
        return f"in all {len(names)} test situations: {message}"
    quoted = ", ".join(f"'{n}'" for n in names)
    return f"situations {quoted}: {message}"


_REFUSED = re.compile(r"^(use of|access to attribute) '([^']+)' is not allowed$")


def _as_permission_error(err: RewardError) -> RewardError:
    """A refused name (``os.system``, ``open``, ``eval``) is a permission problem, not bad
    syntax: report it as DeepRacer's IMPORT_ERROR, saying what is refused and why."""
    match = _REFUSED.match(err.message) if err.type == "SYNTAX_ERROR" else None
    if match is None:
        return err
    return RewardError(
        "IMPORT_ERROR",
        f"'{match.group(2)}' is not permitted in a reward function (no files, processes, "
        "network or introspection)",
        err.line,
        err.column,
    )


def _placed(err: RewardError, source: str) -> RewardError:
    """A bad return value has no traceback; point at the ``return`` that produced it."""
    if err.line is not None or not err.message.startswith("reward_function returned"):
        return err
    lines = _return_lines(source, err.message)
    if len(lines) == 1:
        return RewardError(err.type, err.message, lines[0], err.column)
    if lines:
        where = ", ".join(str(n) for n in lines)
        return RewardError(err.type, f"{err.message} (a return on line {where})", lines[0])
    return err


def _return_lines(source: str, message: str) -> list[int]:
    """Lines of ``reward_function``'s own ``return`` statements that may have given the value
    in ``message``: those returning a literal of the same kind when there are any, else all."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError, RecursionError):
        return []
    defs = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "reward_function"]
    if not defs:
        return []
    returns: list[ast.Return] = []
    todo: list[ast.AST] = list(defs[-1].body)
    while todo:
        node = todo.pop()
        if isinstance(node, ast.Return):
            returns.append(node)
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda | ast.ClassDef):
            todo.extend(ast.iter_child_nodes(node))
    returns.sort(key=lambda r: r.lineno)
    shown = message.removeprefix("reward_function returned ")

    def kind(node: ast.Return) -> str:
        value = node.value
        if value is None or (isinstance(value, ast.Constant) and value.value is None):
            return "none"
        if isinstance(value, ast.JoinedStr) or (
            isinstance(value, ast.Constant) and isinstance(value.value, str)
        ):
            return "str"
        if isinstance(value, ast.List | ast.ListComp | ast.Tuple | ast.Dict | ast.Set):
            return "container"
        return "other"

    wanted = (
        "str" if shown.startswith(("'", '"'))
        else "none" if shown.startswith("None")
        else "container" if shown.startswith(("an object of type list", "an object of type tuple",
                                              "an object of type dict", "an object of type set"))
        else ""
    )  # fmt: skip
    matching = [r.lineno for r in returns if wanted and kind(r) == wanted]
    return matching or [r.lineno for r in returns]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m training.rewards.validation",
        description="Validate a DeepRacer reward function on a track; print JSON.",
    )
    parser.add_argument("path", help="the reward function's .py file")
    parser.add_argument(
        "--tracks-dir",
        default=os.environ.get("RACECRAFT_TRACKS_DIR"),
        help="folder of imported track files (default: $RACECRAFT_TRACKS_DIR, as the console)",
    )
    parser.add_argument("--track", required=True, metavar="TRACK",
                        help="track id: a built-in track or one in the tracks folder")  # fmt: skip
    args = parser.parse_args(argv)
    catalog = TrackCatalog([args.tracks_dir] if args.tracks_dir else [])
    try:
        with open(args.path, encoding="utf-8") as f:
            source = f.read()
        result = validate_reward_function(source, catalog.load(args.track))
    except (OSError, UnicodeDecodeError) as exc:
        print(json.dumps({"ok": False, "usage_error": str(exc)}), file=sys.stderr)
        return 2
    except UnknownTrackError as exc:
        known = ", ".join(catalog.ids())
        print(json.dumps({"ok": False, "usage_error": f"{exc}; known tracks: {known}"}),
              file=sys.stderr)  # fmt: skip
        return 2
    print(json.dumps(result.to_dict(), indent=2))
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
