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
import json
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
    errors = check_source(source)
    if errors:
        return ValidationResult(errors)
    try:
        result = evaluate_reward(source, situation_params(loaded, situations), limits=limits)
    except SandboxUnavailable as exc:
        return ValidationResult([RewardError("TEST_FAILURE", str(exc))])
    rewards: dict[str, float] = {}
    seen: set[tuple[str, str]] = set()
    for name, outcome in zip(situations, result.outcomes, strict=True):
        if outcome.error is None:
            if outcome.value is not None:
                rewards[name] = outcome.value
            continue
        err = outcome.error
        key = (err.type, err.message)
        if key in seen:  # e.g. a module that fails to load fails every situation alike
            continue
        seen.add(key)
        errors.append(
            RewardError(err.type, f"situation '{name}': {err.message}", err.line, err.column)
        )
    warnings = []
    if result.weak:
        warnings.append(
            "This reward function ran with weakened isolation (missing: "
            f"{', '.join(result.weak)}), because the operator set RACECRAFT_ALLOW_WEAK_SANDBOX."
        )
    return ValidationResult(errors, rewards, result.layers, result.output, warnings)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m training.rewards.validation",
        description="Validate a DeepRacer reward function on a track; print JSON.",
    )
    parser.add_argument("path", help="the reward function's .py file")
    parser.add_argument("--track", required=True, help="track id, e.g. racecraft_oval")
    args = parser.parse_args(argv)
    try:
        with open(args.path, encoding="utf-8") as f:
            source = f.read()
        result = validate_reward_function(source, args.track)
    except (OSError, UnicodeDecodeError) as exc:
        print(json.dumps({"ok": False, "usage_error": str(exc)}), file=sys.stderr)
        return 2
    except UnknownTrackError as exc:
        print(json.dumps({"ok": False, "usage_error": str(exc)}), file=sys.stderr)
        return 2
    print(json.dumps(result.to_dict(), indent=2))
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
