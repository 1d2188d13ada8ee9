"""Evaluating a reward function on a list of params dicts (validation, tools), running a target
to completion (:func:`run_sandboxed`), and the small targets the sandbox runs for these, for
the per-call service and for the benchmark."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from training.sandbox import checked
from training.sandbox.child import SandboxContext
from training.sandbox.errors import (
    RewardError,
    RewardFunctionError,
    SandboxError,
    SandboxProtocolError,
    SandboxTimeout,
    SandboxUnavailable,
)
from training.sandbox.guard import copy_params
from training.sandbox.limits import VALIDATION_LIMITS, SandboxLimits
from training.sandbox.process import CALL_SLACK_S, SandboxProcess

EVALUATE_TARGET = "training.sandbox.oneshot:evaluate_main"
SERVE_TARGET = "training.sandbox.oneshot:serve_main"
TIMING_TARGET = "training.sandbox.oneshot:timing_main"


@dataclass(frozen=True)
class RewardOutcome:
    """The reward for one params dict, or the error it caused."""

    value: float | None
    error: RewardError | None = None


@dataclass
class EvaluationResult:
    outcomes: list[RewardOutcome]
    layers: dict[str, str] = field(default_factory=dict)
    output: str = ""
    #: Protections missing but accepted by RACECRAFT_ALLOW_WEAK_SANDBOX; empty normally.
    weak: tuple[str, ...] = ()

    @property
    def errors(self) -> list[RewardError]:
        return [o.error for o in self.outcomes if o.error is not None]


def evaluate_main(ctx: SandboxContext) -> dict[str, Any]:
    """Child target: call the reward on each params dict of ``ctx.args['params']``."""
    for i, params in enumerate(ctx.args["params"]):
        try:
            ctx.send({"i": i, "value": ctx.reward(params)})
        except RewardFunctionError as exc:
            ctx.send({"i": i, "error": exc.error.to_dict()})
    return {}


def serve_main(ctx: SandboxContext) -> int:
    """Child target: answer each params dict received with its reward (one IPC per call)."""
    while (params := ctx.recv()) is not None:
        ctx.send(ctx.reward(params))
    return ctx.reward.step


def timing_main(ctx: SandboxContext) -> dict[str, float]:
    """Child target for the benchmark: time ``n`` guarded calls and ``n`` raw calls."""
    # As the simulator builds them: immutable (x, y) tuples (JSON turned them into lists).
    params, n = copy_params(ctx.args["params"]), int(ctx.args["n"])
    raw = ctx.reward._fn  # noqa: SLF001 - measuring the guard's own cost
    prepared = copy_params(params)
    t0 = time.perf_counter_ns()
    for _ in range(n):
        ctx.reward(params)
    t1 = time.perf_counter_ns()
    for _ in range(n):
        raw(prepared)
    t2 = time.perf_counter_ns()
    return {"guarded_ns": (t1 - t0) / n, "raw_ns": (t2 - t1) / n}


def isolation_support(limits: SandboxLimits | None = None) -> dict[str, str]:
    """Start a sandbox with a trivial reward and return its report of isolation layers:
    ``{layer: "active" | "unavailable: <reason>" | ...}``; it never refuses (our own code),
    see :func:`~training.sandbox.requirements.missing_requirements` for the verdict."""
    source = "def reward_function(params):\n    return 1.0\n"
    sandbox = SandboxProcess(
        target=EVALUATE_TARGET,
        reward_source=source,
        args={"params": []},
        limits=limits,
        allow_weak=True,
    )
    try:
        return sandbox.start()
    finally:
        sandbox.close()


def _crash_error(exc: SandboxError) -> RewardError:
    return RewardError("TEST_FAILURE", str(exc))


def evaluation_seconds(limits: SandboxLimits, calls: int) -> float:
    """The overall limit of an evaluation on the parent's clock: start-up, then each call
    with its limit and slack (a restart after a killed call fits in that slack)."""
    return limits.start_seconds + calls * (limits.per_call_seconds + CALL_SLACK_S)


def _checked_outcome(value: Any, offset: int, size: int) -> tuple[int, RewardOutcome]:
    """``(index, outcome)`` of one evaluate_main message; raises Malformed otherwise."""
    msg = checked.mapping(value, "reward message")
    i = offset + checked.index(msg.get("i"), size - offset, "reward index")
    if "error" in msg:
        err = checked.mapping(msg["error"], "reward error")
        return i, RewardOutcome(None, RewardError.from_dict(err))
    return i, RewardOutcome(checked.number(msg.get("value"), "reward value"))


def evaluate_reward(
    source: str,
    params_list: list[dict[str, Any]],
    *,
    limits: SandboxLimits = VALIDATION_LIMITS,
    python_guards: bool = True,
    disabled_layers: tuple[str, ...] = (),
    deadline_seconds: float | None = None,
    stop_after_timeout: bool = False,
) -> EvaluationResult:
    """Call ``reward_function`` of ``source`` on each params dict, in a sandbox.

    Each call has ``limits.per_call_seconds`` and the whole evaluation ``deadline_seconds``
    (default :func:`evaluation_seconds`), both on this process's clock. An error in one call
    does not stop the others; a call that kills the sandbox (timeout, crash, malformed data)
    is reported and the remaining calls run in a fresh sandbox, while time remains. A module
    that does not load gives the same error for every call.
    With ``stop_after_timeout`` a call that overruns its limit ends the evaluation: the
    outcomes stop there (a function that never returns costs one call's limit, not one per
    params dict).
    Raises SandboxUnavailable (before running any user code) when this machine cannot isolate
    it and weak isolation was not accepted.
    """
    n = len(params_list)
    overall = evaluation_seconds(limits, n) if deadline_seconds is None else deadline_seconds
    deadline = time.monotonic() + overall
    outcomes: list[RewardOutcome | None] = [None] * n
    layers: dict[str, str] = {}
    weak: tuple[str, ...] = ()
    output: list[str] = []
    start = 0
    while start < n:
        left = deadline - time.monotonic()
        if left <= 0:
            late = RewardError(
                "TEST_FAILURE",
                f"Not run: the evaluation passed its overall limit of {overall:g} s.",
            )
            outcomes[start:] = [o or RewardOutcome(None, late) for o in outcomes[start:]]
            break
        sandbox = SandboxProcess(
            target=EVALUATE_TARGET,
            reward_source=source,
            args={"params": params_list[start:]},
            limits=limits,
            python_guards=python_guards,
            disabled_layers=disabled_layers,
            deadline_seconds=left,
        )
        try:
            layers = sandbox.start()
            weak = sandbox.weak
            per_call = limits.per_call_seconds + CALL_SLACK_S
            while True:
                msg = sandbox.recv(per_call, late=sandbox.late_words("reward_function"))
                if msg.kind == "result":
                    output.append(msg.output)
                    break
                i, outcome = _checked_outcome(msg.value, start, n)
                outcomes[i] = outcome
            if any(o is None for o in outcomes[start:]):  # "finished" without every answer
                raise checked.Malformed("the sandbox finished early")
            start = n
        except RewardFunctionError as exc:  # the module did not load
            output.append(sandbox.output)
            return EvaluationResult(
                [RewardOutcome(None, exc.error)] * n, layers, "".join(output), weak
            )
        except SandboxUnavailable:
            raise
        except (SandboxError, checked.Malformed) as exc:
            first = next((j for j in range(start, n) if outcomes[j] is None), start)
            error = (
                _crash_error(exc)
                if isinstance(exc, SandboxError)
                else RewardError("TEST_FAILURE", checked.MALFORMED)
            )
            outcomes[first] = RewardOutcome(None, error)
            start = first + 1
            if stop_after_timeout and isinstance(exc, SandboxTimeout):
                kept = [o for o in outcomes[:start] if o is not None]
                return EvaluationResult(kept, layers, "".join(output), weak)
        finally:
            sandbox.close()
    done = [o if o is not None else RewardOutcome(None, None) for o in outcomes]
    return EvaluationResult(done, layers, "".join(output), weak)


def run_sandboxed(
    *,
    target: str,
    reward_source: str,
    args: Any = None,
    limits: SandboxLimits | None = None,
    prepare: str | None = None,
    on_message: Callable[[Any], None] | None = None,
    timeout: float | None = None,
    python_guards: bool = True,
) -> Any:
    """Run ``target(ctx)`` in a sandbox child and return what it returns.

    Messages the target sends go to ``on_message``. ``timeout`` bounds the whole run (seconds).
    Raises RewardFunctionError or SandboxError (see :class:`SandboxProcess`).
    """
    sandbox = SandboxProcess(
        target=target,
        reward_source=reward_source,
        args=args,
        limits=limits,
        prepare=prepare,
        python_guards=python_guards,
    )
    deadline = None if timeout is None else time.monotonic() + timeout
    sandbox.start()
    try:
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            msg = sandbox.recv(left)
            if msg.kind == "result":
                return msg.value
            if on_message is not None:
                on_message(msg.value)
    finally:
        sandbox.close()


class SandboxedReward:
    """``reward(params) -> float`` with one IPC round trip per call to a long-lived sandbox.

    For callers that need rewards in their own process (tools, offline replays); the rollout
    loop instead runs inside the sandbox. Raises RewardFunctionError / SandboxError.
    """

    def __init__(self, source: str, limits: SandboxLimits | None = None) -> None:
        self._sandbox = SandboxProcess(target=SERVE_TARGET, reward_source=source, limits=limits)
        self.layers = self._sandbox.start()
        self._timeout = self._sandbox.limits.per_call_seconds + CALL_SLACK_S

    def __call__(self, params: dict[str, Any]) -> float:
        self._sandbox.send(params)
        late = self._sandbox.late_words("reward_function")
        msg = self._sandbox.recv(self._timeout, late=late)
        try:
            return checked.number(msg.value, "reward value")
        except checked.Malformed:
            self._sandbox.close()
            raise SandboxProtocolError(checked.MALFORMED) from None

    def close(self) -> None:
        self._sandbox.close()

    def __enter__(self) -> SandboxedReward:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
