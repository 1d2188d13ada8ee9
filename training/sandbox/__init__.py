"""Running untrusted reward functions: a locked-down child process per rollout worker or
validation run, with Python-level guards for good messages and OS layers as the boundary.

Public API::

    SandboxProcess(target=..., reward_source=..., args=..., limits=..., prepare=...)
    run_sandboxed(target="pkg.mod:fn", reward_source=..., args=..., limits=...)
    evaluate_reward(source, params_list, limits=...) -> EvaluationResult
    SandboxedReward(source)  # per-call IPC
    check_source(source) -> list[RewardError]
    isolation_support() -> dict[str, str]
    missing_requirements(layers) -> list[Requirement]   # fail closed: see requirements.py

A target is ``fn(ctx: SandboxContext)``; it runs after lock-down with ``ctx.reward(params)``
(the guarded reward callable), ``ctx.args``, ``ctx.prepared`` (from the optional ``prepare``
hook, run before lock-down), ``ctx.send``/``ctx.recv`` and ``ctx.take_output()``.
"""

from training.sandbox.child import SandboxContext
from training.sandbox.errors import (
    RewardError,
    RewardFunctionError,
    SandboxCrashed,
    SandboxError,
    SandboxProtocolError,
    SandboxStartError,
    SandboxTimeout,
    SandboxUnavailable,
)
from training.sandbox.limits import VALIDATION_LIMITS, SandboxLimits
from training.sandbox.oneshot import (
    EvaluationResult,
    RewardOutcome,
    SandboxedReward,
    evaluate_reward,
    isolation_support,
    run_sandboxed,
)
from training.sandbox.process import SandboxMessage, SandboxProcess
from training.sandbox.requirements import (
    Requirement,
    describe_missing,
    missing_requirements,
    weak_sandbox_allowed,
)
from training.sandbox.static import MAX_SOURCE_CHARS, check_source

__all__ = [
    "MAX_SOURCE_CHARS",
    "VALIDATION_LIMITS",
    "EvaluationResult",
    "RewardError",
    "RewardFunctionError",
    "Requirement",
    "RewardOutcome",
    "SandboxContext",
    "SandboxCrashed",
    "SandboxError",
    "SandboxLimits",
    "SandboxMessage",
    "SandboxProcess",
    "SandboxProtocolError",
    "SandboxStartError",
    "SandboxTimeout",
    "SandboxUnavailable",
    "SandboxedReward",
    "check_source",
    "describe_missing",
    "evaluate_reward",
    "isolation_support",
    "missing_requirements",
    "run_sandboxed",
    "weak_sandbox_allowed",
]
