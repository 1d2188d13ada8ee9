"""Evaluating a reward function on a list of params dicts (validation, tools), and the small
targets the sandbox runs for it, for the per-call service and for the benchmark."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from training.sandbox.child import SandboxContext
from training.sandbox.errors import (
    RewardError,
    RewardFunctionError,
    SandboxError,
    SandboxUnavailable,
)
from training.sandbox.guard import copy_params
from training.sandbox.limits import VALIDATION_LIMITS, SandboxLimits
from training.sandbox.process import SandboxProcess

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


def evaluate_reward(
    source: str,
    params_list: list[dict[str, Any]],
    *,
    limits: SandboxLimits = VALIDATION_LIMITS,
    python_guards: bool = True,
    disabled_layers: tuple[str, ...] = (),
) -> EvaluationResult:
    """Call ``reward_function`` of ``source`` on each params dict, in a sandbox.

    Each call has ``limits.per_call_seconds``. An error in one call does not stop the others;
    a call that kills the sandbox (timeout, crash) is reported and the remaining calls run in
    a fresh sandbox. A module that does not load gives the same error for every call.
    Raises SandboxUnavailable (before running any user code) when this machine cannot isolate
    it and weak isolation was not accepted.
    """
    outcomes: list[RewardOutcome | None] = [None] * len(params_list)
    layers: dict[str, str] = {}
    weak: tuple[str, ...] = ()
    output: list[str] = []
    start = 0
    while start < len(params_list):
        sandbox = SandboxProcess(
            target=EVALUATE_TARGET,
            reward_source=source,
            args={"params": params_list[start:]},
            limits=limits,
            python_guards=python_guards,
            disabled_layers=disabled_layers,
        )
        try:
            layers = sandbox.start()
            weak = sandbox.weak
            while True:
                msg = sandbox.recv()
                if msg.kind == "result":
                    output.append(msg.output)
                    break
                i = start + int(msg.value["i"])
                err = msg.value.get("error")
                outcomes[i] = (
                    RewardOutcome(None, RewardError.from_dict(err))
                    if isinstance(err, dict)
                    else RewardOutcome(float(msg.value["value"]))
                )
            start = len(params_list)
        except RewardFunctionError as exc:  # the module did not load
            output.append(sandbox.output)
            return EvaluationResult(
                [RewardOutcome(None, exc.error)] * len(params_list), layers, "".join(output), weak
            )
        except SandboxUnavailable:
            raise
        except (SandboxError, KeyError, TypeError, ValueError) as exc:
            first = next((j for j in range(start, len(params_list)) if outcomes[j] is None), start)
            error = (
                _crash_error(exc)
                if isinstance(exc, SandboxError)
                else RewardError(
                    "TEST_FAILURE", "The reward function's sandbox sent malformed data."
                )
            )
            outcomes[first] = RewardOutcome(None, error)
            start = first + 1
        finally:
            sandbox.close()
    done = [o if o is not None else RewardOutcome(None, None) for o in outcomes]
    return EvaluationResult(done, layers, "".join(output), weak)


class SandboxedReward:
    """``reward(params) -> float`` with one IPC round trip per call to a long-lived sandbox.

    For callers that need rewards in their own process (tools, offline replays); the rollout
    loop instead runs inside the sandbox. Raises RewardFunctionError / SandboxError.
    """

    def __init__(self, source: str, limits: SandboxLimits | None = None) -> None:
        self._sandbox = SandboxProcess(target=SERVE_TARGET, reward_source=source, limits=limits)
        self.layers = self._sandbox.start()
        self._timeout = self._sandbox.limits.per_call_seconds + 5.0

    def __call__(self, params: dict[str, Any]) -> float:
        self._sandbox.send(params)
        msg = self._sandbox.recv(self._timeout)
        return float(msg.value)

    def close(self) -> None:
        self._sandbox.close()

    def __enter__(self) -> SandboxedReward:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
